"""BVH motion files: read and write any hierarchy.

Supports per-joint channel lists (0 or 3 position channels and 0 or 3 rotation channels
in any order, on any joint), End Sites, CRLF line endings and scientific notation.
Rotations follow the BVH convention: channels ``Zrotation Yrotation Xrotation`` mean
``R = Rz · Ry · Rx`` (see :mod:`bezmotion.geometry.rotations`). Joints are returned in
file order (depth first), End Sites are kept aside so a file can be written back.

A malformed file raises ``ValueError("<file>:<line>: <what is wrong>")``, one line of about
:data:`~bezmotion._src.messages.MESSAGE_CHARS` characters; so does a file beyond the limits
below (nesting, joint count, values), which no real motion comes near. Nothing recurses over
the hierarchy, so no depth gives a ``RecursionError``. Writing is atomic, and refuses what
reading would. Arrays are NumPy float64: I/O is host-side work; convert with ``jnp.asarray``.
"""

from __future__ import annotations

import dataclasses
import decimal
import functools
import io
import os
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

from bezmotion._src.io import atomic_write_text
from bezmotion._src.messages import MESSAGE_CHARS, one_line
from bezmotion.geometry.rotations import euler_from_quat, quat_fix_continuity, quat_from_euler
from bezmotion.geometry.skeleton import Skeleton

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
_CHANNEL_LOOKUP = {name.lower(): name for name in POSITION_CHANNELS + ROTATION_CHANNELS}


FRAME_TIME_RANGE = (1e-5, 60.0)
"""Seconds per frame a motion may have: 100,000 fps down to a frame a minute. Outside it a
``Frame Time`` is a mistake (and its frame rate would overflow)."""

MAX_DEPTH = 256
"""The most joints nested one inside another (the root is at depth 1). A human skeleton is
about 10 deep, a rope, tail or finger chain a few dozen more; deeper nesting is a broken or
hostile file."""

MAX_JOINTS = 4096
"""The most joints a file may declare. Face and finger rigs bring a skeleton to a few
hundred, the largest game rigs to about a thousand."""

MAX_JOINT_FRAMES = 50_000_000
"""The most joints × frames a file may hold (its motion takes about 1.2 GB as float64
positions and rotations then): two hours at 120 fps of a 60-joint skeleton. A few joints
without channels times a million short rows would otherwise ask for tens of gigabytes."""

OFFSET_LIMIT = 1e6
"""The largest ``|x|``, ``|y|`` or ``|z|`` of an ``OFFSET``, in the file's own unit: 1 km in
millimetres (the smallest unit BVH files use), 10 km in centimetres. No bone or rest position
comes near it; a larger number is corrupt (``1e300`` would overflow once squared)."""

POSITION_LIMIT = 1e8
"""The largest ``|value|`` of a position channel, in the file's own unit: 100 km in
millimetres, 1,000 km in centimetres, far beyond any capture volume or walk. Its square still
fits float32, the models' precision."""

ANGLE_LIMIT = 1e6
"""The largest ``|value|`` of a rotation channel, degrees: 2,777 turns, more than an exporter
that never wraps its angles reaches. float64 resolves 10⁻¹⁰ degrees there; past about 10¹⁷
degrees an angle no longer tells one turn from the next."""


@dataclasses.dataclass(frozen=True)
class BvhMotion:
    """An animated hierarchy as stored in a BVH file.

    Attributes:
      skeleton: joints in file order; ``offsets`` are the OFFSET lines (cm).
      quat_local: ``(frames, joints, 4)`` local rotations (w, x, y, z), float64.
      pos_local: ``(frames, joints, 3)`` local translations (cm): the animated position
        channels where a joint has them, its OFFSET elsewhere.
      channels: channel names per joint, as written in the file.
      frame_time: seconds per frame.
      end_sites: ``(parent joint index, (x, y, z) offset)`` of every End Site.
      frame_time_decimals: how many decimals the file wrote ``Frame Time`` to (``0.03333``: 5),
        which says how far it may be from the rate it stands for; ``None`` when not read from
        a file.
    """

    skeleton: Skeleton
    quat_local: np.ndarray
    pos_local: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    end_sites: tuple[tuple[int, tuple[float, float, float]], ...] = ()
    frame_time_decimals: int | None = None

    def __post_init__(self) -> None:
        j = self.skeleton.num_joints
        if self.quat_local.ndim != 3 or self.quat_local.shape[1:] != (j, 4):
            raise ValueError(f"quat_local must have shape (frames, {j}, 4), got {self.quat_local.shape}")
        if self.pos_local.shape != self.quat_local.shape[:2] + (3,):
            raise ValueError(f"pos_local must have shape {self.quat_local.shape[:2] + (3,)}, got {self.pos_local.shape}")
        if len(self.channels) != j:
            raise ValueError(f"{len(self.channels)} channel lists for {j} joints")
        for name, chans in zip(self.skeleton.names, self.channels):
            _rotation_order(chans, where=f"joint {name!r}")
        if not (np.isfinite(self.frame_time) and FRAME_TIME_RANGE[0] <= self.frame_time <= FRAME_TIME_RANGE[1]):
            raise ValueError(f"frame_time must be {FRAME_TIME_RANGE[0]:g} … {FRAME_TIME_RANGE[1]:g} seconds, got {self.frame_time}")

    @property
    def num_frames(self) -> int:
        return self.quat_local.shape[0]

    @property
    def root_pos(self) -> np.ndarray:
        """``(frames, 3)`` root translation (cm)."""
        return self.pos_local[:, 0]

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def nominal_fps(self) -> float:
        """The whole frame rate the written frame time stands for, rounded or cut off
        (``0.0333333`` and ``0.03333`` → ``30.0``, not ``30.00003`` or ``30.003``); :attr:`fps`
        when there is none (``0.033367``: 29.97)."""
        whole = round(self.fps)
        # A frame time rounded or cut off to d decimals lies within 10^-d s of 1/whole. Fewer
        # than 4 decimals say too little (0.017 fits 59 and 60 fps): the value is taken as it is.
        decimals = self.frame_time_decimals
        tolerance = 10.0**-decimals if decimals is not None and 4 <= decimals < 6 else 1e-6
        return float(whole) if whole >= 1 and abs(self.frame_time - 1.0 / whole) < tolerance else self.fps

    @classmethod
    def from_skeleton(
        cls,
        skeleton: Skeleton,
        quat_local,
        root_pos,
        *,
        frame_time: float = 1.0 / 30.0,
        rotation_order: str = "zyx",
        end_sites: Sequence[tuple[int, tuple[float, float, float]]] = (),
    ) -> "BvhMotion":
        """A motion with the usual layout: 6 channels on the root, 3 rotation channels elsewhere."""
        order = rotation_order.lower()
        rot = tuple(f"{a.upper()}rotation" for a in order)
        channels = (POSITION_CHANNELS + rot,) + (rot,) * (skeleton.num_joints - 1)
        quat_local = np.asarray(quat_local, np.float64)
        offsets = np.asarray(skeleton.offsets, np.float64)
        pos_local = np.broadcast_to(offsets, quat_local.shape[:2] + (3,)).copy()
        pos_local[:, 0] = np.asarray(root_pos, np.float64)
        return cls(skeleton, quat_local, pos_local, channels, float(frame_time), tuple(end_sites))


def _rotation_order(channels: Sequence[str], where: str) -> str:
    """The rotation order string (e.g. ``"zyx"``) of a channel list, ``""`` if it has none."""
    rot = [c[0].lower() for c in channels if c in ROTATION_CHANNELS]
    pos = [c for c in channels if c in POSITION_CHANNELS]
    unknown = [c for c in channels if c not in ROTATION_CHANNELS and c not in POSITION_CHANNELS]
    if unknown:
        raise ValueError(f"{where}: unknown channel(s) {unknown}")
    if len(rot) not in (0, 3) or len(set(rot)) != len(rot):
        raise ValueError(f"{where}: rotation channels must be three distinct axes, got {list(channels)}")
    if len(pos) not in (0, 3) or len(set(pos)) != len(pos):
        raise ValueError(f"{where}: position channels must be three distinct axes, got {list(channels)}")
    return "".join(rot)


# ------------------------------------------------------------------------------- reading


class _Reader:
    """Line-oriented hierarchy parser that knows where it is, for error messages."""

    def __init__(self, lines: list[str], source: str):
        self.lines = lines
        self.source = source
        self.i = 0  # index of the next line to read

    def error(self, message: str, line_index: int | None = None) -> ValueError:
        """``ValueError("<source>:<line>: <message>")``, the message cut to fit one line."""
        lineno = max(1, self.i if line_index is None else line_index + 1)  # an empty file's "line 1"
        prefix = f"{self.source}:{lineno}: "
        return ValueError(prefix + one_line(message, max(MESSAGE_CHARS - len(prefix), 100)))

    def next_tokens(self) -> list[str]:
        """Tokens of the next non-empty line (raises at end of file)."""
        while self.i < len(self.lines):
            tokens = self.lines[self.i].split()
            self.i += 1
            if tokens:
                return tokens
        if not any(line.strip() for line in self.lines):
            raise self.error("the file has only blank lines" if self.lines else "the file is empty", 0)
        raise self.error("unexpected end of file", len(self.lines) - 1)

    def floats(self, tokens: Sequence[str], what: str, limit: float) -> list[float]:
        """``tokens`` as finite numbers of at most ``limit`` in size (raises naming the first other)."""
        try:
            values = [float(t) for t in tokens]
        except ValueError:
            raise self.error(f"{what}: expected numbers, got {' '.join(tokens)!r}") from None
        for token, value in zip(tokens, values):
            if not np.isfinite(value):
                raise self.error(f"{what}: non-finite value {token!r} in {' '.join(tokens)!r}")
            if abs(value) > limit:
                raise self.error(f"{what}: {token} is out of range, beyond ±{limit:g}")
        return values


@dataclasses.dataclass
class _Block:
    """A ``ROOT``/``JOINT`` or End Site block being read: its joint (``-1`` for an End Site)
    and parent, and whether its OFFSET has been read."""

    joint: int
    parent: int
    name: str
    have_offset: bool = False


def _parse_hierarchy(reader: _Reader):
    """``(names, parents, offsets, channels, end_sites)`` of the HIERARCHY section.

    An explicit stack of open blocks rather than recursion: a file nested thousands deep is
    refused by :data:`MAX_DEPTH` with its line, not by Python's recursion limit.
    """
    names: list[str] = []
    known: set[str] = set()
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_sites: list[tuple[int, tuple[float, float, float]]] = []
    open_blocks: list[_Block] = []

    def open_block(tokens: list[str], parent: int, is_end_site: bool) -> None:
        # tokens: the declaration line (ROOT/JOINT name, or End Site), possibly ending in '{'.
        decl_line = reader.i
        opened = tokens[-1] == "{"
        if opened:
            tokens = tokens[:-1]
        if is_end_site:
            block = _Block(-1, parent, "End Site")
        else:
            if len(tokens) < 2:
                raise reader.error(f"{tokens[0]} without a joint name")
            name = " ".join(tokens[1:])
            if name in known:
                raise reader.error(f"joint name {name!r} is used twice")
            if len(names) == MAX_JOINTS:
                raise reader.error(f"more than {MAX_JOINTS} joints")
            if len(open_blocks) == MAX_DEPTH:
                raise reader.error(f"joints nested more than {MAX_DEPTH} deep")
            block = _Block(len(names), parent, name)
            names.append(name)
            known.add(name)
            parents.append(parent)
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
        if not opened:
            t = reader.next_tokens()
            if t != ["{"]:
                raise reader.error(f"expected '{{' after the declaration on line {decl_line}, got {' '.join(t)!r}")
        open_blocks.append(block)

    tokens = reader.next_tokens()
    if tokens[0].upper() != "HIERARCHY":
        raise reader.error(f"expected 'HIERARCHY', got {' '.join(tokens)!r}")
    tokens = reader.next_tokens()
    if tokens[0].upper() != "ROOT":
        raise reader.error(f"expected 'ROOT <name>', got {' '.join(tokens)!r}")
    open_block(tokens, -1, False)
    while open_blocks:
        block = open_blocks[-1]
        is_end_site = block.joint < 0
        t = reader.next_tokens()
        key = t[0].upper()
        if t == ["}"]:
            if not block.have_offset:
                raise reader.error(f"missing OFFSET in {block.name!r}")
            open_blocks.pop()
        elif key == "OFFSET":
            if len(t) != 4:
                raise reader.error(f"OFFSET needs 3 numbers, got {len(t) - 1}")
            value = reader.floats(t[1:], "OFFSET", OFFSET_LIMIT)
            block.have_offset = True
            if is_end_site:
                end_sites.append((block.parent, tuple(value)))
            else:
                offsets[block.joint] = value
        elif key == "CHANNELS":
            if is_end_site:
                raise reader.error("an End Site cannot have CHANNELS")
            try:
                count = int(t[1])
            except (IndexError, ValueError):
                raise reader.error(f"CHANNELS needs a count, got {' '.join(t)!r}") from None
            if count != len(t) - 2:
                raise reader.error(f"CHANNELS announces {count} channels but lists {len(t) - 2}")
            chans = []
            for c in t[2:]:
                if c.lower() not in _CHANNEL_LOOKUP:
                    raise reader.error(f"unknown channel {c!r}")
                chans.append(_CHANNEL_LOOKUP[c.lower()])
            try:
                _rotation_order(chans, where=f"joint {block.name!r}")
            except ValueError as e:
                raise reader.error(str(e)) from None
            channels[block.joint] = tuple(chans)
        elif key == "JOINT" and not is_end_site:
            open_block(t, block.joint, False)
        elif key == "END" and not is_end_site:
            if len(t) < 2 or t[1].upper() != "SITE":
                raise reader.error(f"expected 'End Site', got {' '.join(t)!r}")
            open_block(t[1:], block.joint, True)
        else:
            raise reader.error(f"unexpected {' '.join(t)!r} inside {block.name!r}")
    return names, parents, offsets, channels, end_sites


def _header_value(reader: _Reader, label: str, what: str, convert):
    """The value of the next line, which must read ``<label>: <value>``."""
    joined = " ".join(reader.next_tokens())
    expected = f"expected '{label}: <{what}>', got {joined!r}"
    if not joined.lower().startswith(label.lower() + ":"):
        raise reader.error(expected)
    try:
        return convert(joined.split(":", 1)[1])
    except ValueError:
        raise reader.error(expected) from None


def _parse_motion_header(reader: _Reader, num_joints: int) -> tuple[int, float, int | None]:
    """``(frames, frame time in s, the frame time's written decimals)`` of the MOTION header
    of a hierarchy of ``num_joints`` joints."""
    t = reader.next_tokens()
    if t[0].upper() == "ROOT":
        raise reader.error("more than one ROOT is not supported")
    if t[0].upper() != "MOTION":
        raise reader.error(f"expected 'MOTION' after the hierarchy, got {' '.join(t)!r}")
    frames = _header_value(reader, "Frames", "count", int)
    if frames < 0:
        raise reader.error(f"negative frame count {frames}")
    if frames * num_joints > MAX_JOINT_FRAMES:
        raise reader.error(f"{frames} frames of {num_joints} joints: more than {MAX_JOINT_FRAMES:,} joint-frames; split the file")
    written = _header_value(reader, "Frame Time", "seconds", _decimal)
    frame_time = float(written)
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise reader.error(f"Frame Time must be positive, got {frame_time}")
    if not FRAME_TIME_RANGE[0] <= frame_time <= FRAME_TIME_RANGE[1]:
        raise reader.error(f"Frame Time must lie in {FRAME_TIME_RANGE[0]:g} … {FRAME_TIME_RANGE[1]:g} s, got {frame_time:g}")
    exponent = written.as_tuple().exponent  # 0.03333 and 3.333e-02: -5
    return frames, frame_time, -exponent if isinstance(exponent, int) else None


def _decimal(text: str) -> decimal.Decimal:
    """``text`` as a decimal number, keeping how many decimals it was written with.

    Raises:
      ValueError: not a number.
    """
    try:
        value = decimal.Decimal(text.strip())
    except decimal.InvalidOperation:
        raise ValueError(f"not a number: {text!r}") from None
    if value.is_snan():  # float() refuses a signalling NaN; a quiet one reads as nan
        return decimal.Decimal("NaN")
    return value


def _parse_motion_data(reader: _Reader, frames: int, columns: Sequence[tuple[str, str]]) -> np.ndarray:
    """``(frames, channels)`` float64 values, each finite and within its channel's limit
    (:data:`POSITION_LIMIT`, :data:`ANGLE_LIMIT`); ``columns`` names each channel
    ``(joint, channel)``. A fast path first, line-by-line diagnosis on failure."""
    num_channels = len(columns)
    limits = np.asarray([POSITION_LIMIT if c in POSITION_CHANNELS else ANGLE_LIMIT for _, c in columns], np.float64)
    start = reader.i
    rows = reader.lines[start:]
    try:
        values = np.array(" ".join(rows).split(), dtype=np.float64)
        # NaN compares False, so this refuses non-finite values too.
        ok = values.size == frames * num_channels and (np.abs(values.reshape(frames, num_channels)) <= limits).all()
    except ValueError:
        ok = False
    if ok:
        # The count can match by accident with ragged rows; check the rows themselves.
        nonempty = [r for r in rows if r.strip()]
        if len(nonempty) == frames and all(len(r.split()) == num_channels for r in nonempty):
            return values.reshape(frames, num_channels)
    table = []
    for k, row in enumerate(rows):
        tokens = row.split()
        if not tokens:
            continue
        idx, seen = start + k, len(table)
        if seen == frames:
            raise reader.error(f"more motion rows than the {frames} announced by 'Frames:'", idx)
        if len(tokens) != num_channels:
            raise reader.error(f"frame {seen} has {len(tokens)} values, the hierarchy declares {num_channels} channels", idx)
        bad = next((tok for tok in tokens if not _is_float(tok)), None)
        if bad is not None:
            raise reader.error(f"frame {seen}: {bad!r} is not a number", idx)
        v = np.array([float(tok) for tok in tokens], np.float64)
        outside = np.flatnonzero(~(np.abs(v) <= limits))
        if outside.size:
            c = int(outside[0])
            (joint, channel), token = columns[c], tokens[c]
            if not np.isfinite(v[c]):
                raise reader.error(f"frame {seen}: non-finite value {token!r} in {joint} {channel}", idx)
            unit = " degrees" if channel in ROTATION_CHANNELS else ""
            raise reader.error(f"frame {seen}: {joint} {channel} {token} is out of range, beyond ±{limits[c]:g}{unit}", idx)
        table.append(v)
    if len(table) != frames:
        raise reader.error(f"'Frames:' announces {frames} frames but the file has {len(table)}", len(reader.lines) - 1)
    return np.reshape(table, (frames, num_channels))  # numbers NumPy would not read but Python does (none known)


def _is_float(token: str) -> bool:
    try:
        float(token)
        return True
    except ValueError:
        return False


def _bucket(n: int) -> int:
    """Pad sizes to powers of two (≥ 1024) so the jitted converters compile a handful of times."""
    return max(1024, 1 << (max(n, 1) - 1).bit_length())


@functools.partial(jax.jit, static_argnames="order")
def _quat_from_euler_jit(angles, order):
    return quat_from_euler(angles, order)


@functools.partial(jax.jit, static_argnames="order")
def _euler_from_quat_jit(quat, order):
    return euler_from_quat(quat, order)


def _convert_padded(fn, x: np.ndarray, order: str, out_dim: int) -> np.ndarray:
    """Apply a jitted per-row converter to ``(n, d)`` float64 rows, padded to a bucket size."""
    n = x.shape[0]
    padded = np.zeros((_bucket(n), x.shape[1]), np.float64)
    padded[:n] = x
    if x.shape[1] == 4:
        padded[n:, 0] = 1.0  # identity quaternions in the padding
    with jax.enable_x64(True):
        out = np.asarray(fn(padded, order))
    return out[:n].reshape(n, out_dim)


def _continuity_fixed(quat: np.ndarray) -> np.ndarray:
    frames, joints, _ = quat.shape
    padded = np.zeros((_bucket(frames), joints, 4), np.float64)
    padded[:frames] = quat
    padded[frames:, :, 0] = 1.0
    with jax.enable_x64(True):
        return np.asarray(_fix_continuity_jit(padded))[:frames]


_fix_continuity_jit = jax.jit(quat_fix_continuity)


def parse_bvh(text: str, source: str = "<string>", *, fix_continuity: bool = True) -> BvhMotion:
    """Parse BVH text; ``source`` names the file in error messages.

    With ``fix_continuity`` the quaternion signs are made continuous over time (frame t
    negated when its dot product with frame t-1 is negative), as the LaFAN1 reader does.

    Raises:
      ValueError: ``"<source>:<line>: <what is wrong>"`` on one line: a malformed file, or
        one beyond :data:`FRAME_TIME_RANGE`, :data:`MAX_DEPTH`, :data:`MAX_JOINTS`,
        :data:`MAX_JOINT_FRAMES`, :data:`OFFSET_LIMIT`, :data:`POSITION_LIMIT` or :data:`ANGLE_LIMIT` (a value that
        is not finite included); the message names the value.
    """
    reader = _Reader(text.splitlines(), source)
    names, parents, offsets, channels, end_sites = _parse_hierarchy(reader)
    frames, frame_time, frame_time_decimals = _parse_motion_header(reader, len(names))
    columns = [(name, c) for name, chans in zip(names, channels) for c in chans]
    data = _parse_motion_data(reader, frames, columns)

    num_joints = len(names)
    offsets_np = np.asarray(offsets, np.float64)
    pos_local = np.broadcast_to(offsets_np, (frames, num_joints, 3)).copy()
    quat_local = np.zeros((frames, num_joints, 4), np.float64)
    quat_local[..., 0] = 1.0

    # Gather columns per rotation order so each order is converted in one batched call.
    by_order: dict[str, tuple[list[int], list[list[int]]]] = {}
    column = 0
    for j, chans in enumerate(channels):
        rot_cols = []
        for c in chans:
            if c in POSITION_CHANNELS:
                pos_local[:, j, POSITION_CHANNELS.index(c)] = data[:, column]
            else:
                rot_cols.append(column)
            column += 1
        if rot_cols:
            order = _rotation_order(chans, where=f"joint {names[j]!r}")
            joints, cols = by_order.setdefault(order, ([], []))
            joints.append(j)
            cols.append(rot_cols)
    for order, (joints, cols) in by_order.items():
        angles = np.deg2rad(data[:, np.asarray(cols)])  # (frames, n, 3)
        q = _convert_padded(_quat_from_euler_jit, angles.reshape(-1, 3), order, 4)
        quat_local[:, joints] = q.reshape(frames, len(joints), 4)
    if fix_continuity and frames > 1:
        quat_local = _continuity_fixed(quat_local)

    try:
        skeleton = Skeleton(tuple(parents), tuple(names), offsets_np)
    except ValueError as e:
        raise ValueError(f"{source}: {e}") from None
    return BvhMotion(skeleton, quat_local, pos_local, tuple(channels), frame_time, tuple(end_sites), frame_time_decimals)


def read_bvh(path: str | os.PathLike, *, fix_continuity: bool = True) -> BvhMotion:
    """Read a BVH file (any hierarchy; UTF-8, else Latin-1); see :func:`parse_bvh`.

    Raises:
      FileNotFoundError: no such file (other ``OSError``: unreadable).
      ValueError: as :func:`parse_bvh`, naming ``path`` and the line.
    """
    path = Path(path)
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return parse_bvh(text, str(path), fix_continuity=fix_continuity)


# ------------------------------------------------------------------------------- writing


def _dfs_order(parents: Sequence[int]) -> list[int]:
    children: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        children.setdefault(p, []).append(j)
    order: list[int] = []
    stack = [0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children.get(j, [])))
    return order


def _format_row(values: Sequence[float] | np.ndarray, precision: int) -> str:
    return " ".join(f"{v:.{precision}f}" for v in values)


def _outside(values: np.ndarray, limit: float = np.inf) -> tuple[int, ...] | None:
    """Index of the first of ``values`` that is not finite or exceeds ``limit`` in size; ``None`` if none."""
    bad = ~(np.isfinite(values) & (np.abs(values) <= limit))
    return tuple(int(i) for i in np.argwhere(bad)[0]) if bad.any() else None


def _check_writable(motion: BvhMotion) -> None:
    """Refuse up front what :func:`parse_bvh` would not read back.

    Joint names that would read back otherwise (empty, line breaks, runs of spaces), NaN or
    inf (the NaN-safe Euler conversion would quietly turn them into 0°), positions beyond
    :data:`POSITION_LIMIT`, offsets beyond :data:`OFFSET_LIMIT`, more than
    :data:`MAX_JOINTS` joints or nesting deeper than :data:`MAX_DEPTH`.

    Raises:
      ValueError: naming the value, its joint and (for motion) its frame.
    """
    skel = motion.skeleton

    def joint(j: int) -> str:
        return f"joint {j} ({skel.names[j]!r})"

    if skel.num_joints > MAX_JOINTS:
        raise ValueError(f"cannot write {skel.num_joints} joints: a BVH file holds at most {MAX_JOINTS}")
    for j, name in enumerate(skel.names):
        # The reader takes the rest of a ROOT/JOINT line, words joined by one space, less a final "{".
        if not name.split() or " ".join(name.split()) != name or name.split()[-1] == "{":
            raise ValueError(one_line(f"cannot write {joint(j)}: a joint's name is words joined by single spaces, not ending in '{{'"))
    depth = [1] * skel.num_joints
    for j, p in enumerate(skel.parents[1:], start=1):  # parents precede their children
        depth[j] = depth[p] + 1
    if max(depth) > MAX_DEPTH:
        deepest = depth.index(max(depth))
        raise ValueError(one_line(f"cannot write {joint(deepest)}, nested {max(depth)} deep: a BVH file nests at most {MAX_DEPTH} joints"))
    for field in ("quat_local", "pos_local"):
        at = _outside(getattr(motion, field))
        if at is not None:
            raise ValueError(one_line(f"cannot write non-finite {field} at frame {at[0]}, {joint(at[1])}"))
    positioned = [j for j, chans in enumerate(motion.channels) if set(chans) & set(POSITION_CHANNELS)]
    at = _outside(motion.pos_local[:, positioned], POSITION_LIMIT)
    if at is not None:
        value, frame, j = motion.pos_local[:, positioned][at], at[0], positioned[at[1]]
        raise ValueError(one_line(f"cannot write pos_local {value:g} at frame {frame}, {joint(j)}: a position channel is at most {POSITION_LIMIT:g} in size"))
    offsets = np.asarray(skel.offsets, np.float64)
    at = _outside(offsets, OFFSET_LIMIT)
    if at is not None:
        raise ValueError(one_line(f"cannot write the OFFSET {offsets[at]:g} of {joint(at[-2])}: an OFFSET is finite and at most {OFFSET_LIMIT:g} in size"))
    sites = np.asarray([offset for _, offset in motion.end_sites], np.float64).reshape(-1, 3)
    at = _outside(sites, OFFSET_LIMIT)
    if at is not None:
        parent = motion.end_sites[at[0]][0]
        raise ValueError(one_line(f"cannot write the End Site OFFSET {sites[at]:g} under {joint(parent)}: an OFFSET is finite and at most {OFFSET_LIMIT:g} in size"))


def format_bvh(motion: BvhMotion, *, precision: int = 6) -> str:
    """BVH text of ``motion``; angles in degrees, ``precision`` decimals everywhere but the
    frame time, which is written exactly (shortest round-trip repr).

    Joints are written depth first; for a skeleton stored in another order the file's
    joint order (and that of a re-read motion) is the depth-first one.

    Raises:
      ValueError: ``precision`` outside 0…15, or a motion :func:`parse_bvh` would not read
        back: a value that is not finite or beyond :data:`OFFSET_LIMIT` /
        :data:`POSITION_LIMIT`, more than :data:`MAX_JOINTS` joints or nesting deeper than
        :data:`MAX_DEPTH` (the message names the value, joint and frame).
    """
    if not (isinstance(precision, int) and 0 <= precision <= 15):
        raise ValueError(f"precision must be an integer in [0, 15], got {precision!r}")
    _check_writable(motion)
    skel = motion.skeleton
    offsets = np.asarray(skel.offsets, np.float64)
    order = _dfs_order(skel.parents)
    children: dict[int, list[int]] = {}
    for j, p in enumerate(skel.parents):
        children.setdefault(p, []).append(j)
    sites: dict[int, list[tuple[float, float, float]]] = {}
    for parent, off in motion.end_sites:
        sites.setdefault(parent, []).append(off)

    out = io.StringIO()
    out.write("HIERARCHY\n")

    # An explicit stack rather than recursion, so that no depth meets Python's recursion limit:
    # (joint, depth, closing) — a joint is opened, its children written, then it is closed.
    stack = [(0, 0, False)]
    while stack:
        j, depth, closing = stack.pop()
        pad = "\t" * depth
        if closing:
            for off in sites.get(j, []):
                out.write(f"{pad}\tEnd Site\n{pad}\t{{\n{pad}\t\tOFFSET {_format_row(off, precision)}\n{pad}\t}}\n")
            out.write(f"{pad}}}\n")
            continue
        keyword = "ROOT" if j == 0 else "JOINT"
        out.write(f"{pad}{keyword} {skel.names[j]}\n{pad}{{\n")
        out.write(f"{pad}\tOFFSET {_format_row(offsets[j], precision)}\n")
        if motion.channels[j]:
            out.write(f"{pad}\tCHANNELS {len(motion.channels[j])} {' '.join(motion.channels[j])}\n")
        stack.append((j, depth, True))
        stack.extend((c, depth + 1, False) for c in reversed(children.get(j, [])))
    frames = motion.num_frames
    out.write(f"MOTION\nFrames: {frames}\nFrame Time: {float(motion.frame_time)!r}\n")  # shortest exact repr

    # Build the (frames, channels) table column by column in file order.
    columns: list[np.ndarray] = []
    for j in order:
        chans = motion.channels[j]
        rot_order = _rotation_order(chans, where=f"joint {skel.names[j]!r}")
        euler = None
        if rot_order:
            euler = np.rad2deg(_convert_padded(_euler_from_quat_jit, motion.quat_local[:, j], rot_order, 3))
        r = 0
        for c in chans:
            if c in POSITION_CHANNELS:
                columns.append(motion.pos_local[:, j, POSITION_CHANNELS.index(c)])
            else:
                columns.append(euler[:, r])
                r += 1
    table = np.stack(columns, axis=1) if columns else np.zeros((frames, 0))
    if not np.isfinite(table).all():
        bad = np.argwhere(~np.isfinite(table))[0]
        raise ValueError(f"cannot write non-finite motion value at frame {bad[0]}, channel {bad[1]}")
    np.savetxt(out, table, fmt=f"%.{precision}f", delimiter=" ")
    return out.getvalue()


def write_bvh(path: str | os.PathLike, motion: BvhMotion, *, precision: int = 6) -> None:
    """Write ``motion`` to ``path`` atomically (LF line endings); see :func:`format_bvh`."""
    atomic_write_text(path, format_bvh(motion, precision=precision))
