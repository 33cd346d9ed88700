"""BVH motion files: read and write any hierarchy.

Supports per-joint channel lists (0 or 3 position channels and 0 or 3 rotation channels
in any order, on any joint), End Sites, CRLF line endings and scientific notation.
Rotations follow the BVH convention: channels ``Zrotation Yrotation Xrotation`` mean
``R = Rz · Ry · Rx`` (see :mod:`bezmotion.geometry.rotations`). Joints are returned in
file order (depth first), End Sites are kept aside so a file can be written back.

A malformed file raises ``ValueError("<file>:<line>: <what is wrong>")``. Writing is
atomic. Arrays are NumPy float64: I/O is host-side work; convert with ``jnp.asarray``.
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
from bezmotion.geometry.rotations import euler_from_quat, quat_fix_continuity, quat_from_euler
from bezmotion.geometry.skeleton import Skeleton

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
_CHANNEL_LOOKUP = {name.lower(): name for name in POSITION_CHANNELS + ROTATION_CHANNELS}


FRAME_TIME_RANGE = (1e-5, 60.0)
"""Seconds per frame a motion may have: 100,000 fps down to a frame a minute. Outside it a
``Frame Time`` is a mistake (and its frame rate would overflow)."""


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
        lineno = (self.i if line_index is None else line_index + 1)
        return ValueError(f"{self.source}:{lineno}: {message}")

    def next_tokens(self) -> list[str]:
        """Tokens of the next non-empty line (raises at end of file)."""
        while self.i < len(self.lines):
            tokens = self.lines[self.i].split()
            self.i += 1
            if tokens:
                return tokens
        raise ValueError(f"{self.source}:{len(self.lines)}: unexpected end of file")

    def floats(self, tokens: Sequence[str], what: str) -> list[float]:
        try:
            values = [float(t) for t in tokens]
        except ValueError:
            raise self.error(f"{what}: expected numbers, got {' '.join(tokens)!r}") from None
        if not all(np.isfinite(values)):
            raise self.error(f"{what}: non-finite value in {' '.join(tokens)!r}")
        return values


def _parse_hierarchy(reader: _Reader):
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_sites: list[tuple[int, tuple[float, float, float]]] = []

    tokens = reader.next_tokens()
    if tokens[0].upper() != "HIERARCHY":
        raise reader.error(f"expected 'HIERARCHY', got {' '.join(tokens)!r}")
    tokens = reader.next_tokens()
    if tokens[0].upper() != "ROOT":
        raise reader.error(f"expected 'ROOT <name>', got {' '.join(tokens)!r}")

    def parse_block(tokens: list[str], parent: int, is_end_site: bool) -> None:
        # tokens: the declaration line (ROOT/JOINT name, or End Site), possibly ending in '{'.
        decl_line = reader.i
        opened = tokens[-1] == "{"
        if opened:
            tokens = tokens[:-1]
        if is_end_site:
            joint = -1
        else:
            if len(tokens) < 2:
                raise reader.error(f"{tokens[0]} without a joint name")
            name = " ".join(tokens[1:])
            if name in names:
                raise reader.error(f"joint name {name!r} is used twice")
            joint = len(names)
            names.append(name)
            parents.append(parent)
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
        if not opened:
            t = reader.next_tokens()
            if t != ["{"]:
                raise reader.error(f"expected '{{' after the declaration on line {decl_line}, got {' '.join(t)!r}")
        have_offset = False
        while True:
            t = reader.next_tokens()
            key = t[0].upper()
            if t == ["}"]:
                break
            if key == "OFFSET":
                if len(t) != 4:
                    raise reader.error(f"OFFSET needs 3 numbers, got {len(t) - 1}")
                value = reader.floats(t[1:], "OFFSET")
                have_offset = True
                if is_end_site:
                    end_sites.append((parent, tuple(value)))
                else:
                    offsets[joint] = value
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
                    _rotation_order(chans, where=f"joint {names[joint]!r}")
                except ValueError as e:
                    raise reader.error(str(e)) from None
                channels[joint] = tuple(chans)
            elif key == "JOINT" and not is_end_site:
                parse_block(t, joint, False)
            elif key == "END" and not is_end_site:
                if len(t) < 2 or t[1].upper() != "SITE":
                    raise reader.error(f"expected 'End Site', got {' '.join(t)!r}")
                parse_block(t[1:], joint, True)
            else:
                raise reader.error(f"unexpected {' '.join(t)!r} inside {'End Site' if is_end_site else names[joint]!r}")
        if not have_offset:
            raise reader.error(f"missing OFFSET in {'End Site' if is_end_site else names[joint]!r}")

    parse_block(tokens, -1, False)
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


def _parse_motion_header(reader: _Reader) -> tuple[int, float, int | None]:
    """``(frames, frame time in s, the frame time's written decimals)`` of the MOTION header."""
    t = reader.next_tokens()
    if t[0].upper() == "ROOT":
        raise reader.error("more than one ROOT is not supported")
    if t[0].upper() != "MOTION":
        raise reader.error(f"expected 'MOTION' after the hierarchy, got {' '.join(t)!r}")
    frames = _header_value(reader, "Frames", "count", int)
    if frames < 0:
        raise reader.error(f"negative frame count {frames}")
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


def _parse_motion_data(reader: _Reader, frames: int, num_channels: int) -> np.ndarray:
    """``(frames, num_channels)`` float64 values; fast path first, line-by-line diagnosis on failure."""
    start = reader.i
    rows = reader.lines[start:]
    try:
        values = np.array(" ".join(rows).split(), dtype=np.float64)
        ok = values.size == frames * num_channels and np.isfinite(values).all()
    except ValueError:
        ok = False
    if ok:
        # The count can match by accident with ragged rows; check the rows themselves.
        nonempty = [r for r in rows if r.strip()]
        if len(nonempty) == frames and all(len(r.split()) == num_channels for r in nonempty):
            return values.reshape(frames, num_channels)
    seen = 0
    for k, row in enumerate(rows):
        tokens = row.split()
        if not tokens:
            continue
        idx = start + k
        if seen == frames:
            raise reader.error(f"more motion rows than the {frames} announced by 'Frames:'", idx)
        if len(tokens) != num_channels:
            raise reader.error(f"frame {seen} has {len(tokens)} values, the hierarchy declares {num_channels} channels", idx)
        try:
            v = np.array(tokens, dtype=np.float64)
        except ValueError:
            bad = next(tok for tok in tokens if not _is_float(tok))
            raise reader.error(f"frame {seen}: {bad!r} is not a number", idx) from None
        if not np.isfinite(v).all():
            raise reader.error(f"frame {seen}: non-finite value", idx)
        seen += 1
    raise reader.error(f"'Frames:' announces {frames} frames but the file has {seen}", len(reader.lines) - 1)


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
    """
    reader = _Reader(text.splitlines(), source)
    names, parents, offsets, channels, end_sites = _parse_hierarchy(reader)
    frames, frame_time, frame_time_decimals = _parse_motion_header(reader)
    num_channels = sum(len(c) for c in channels)
    data = _parse_motion_data(reader, frames, num_channels)

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
    """Read a BVH file (any hierarchy); see :func:`parse_bvh`."""
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


def _check_finite(motion: BvhMotion) -> None:
    """Refuse NaN/inf up front: the NaN-safe Euler conversion would quietly turn them into 0°."""
    for field in ("quat_local", "pos_local"):
        bad = ~np.isfinite(getattr(motion, field))
        if bad.any():
            frame, joint = (int(i) for i in np.argwhere(bad)[0][:2])
            raise ValueError(
                f"cannot write non-finite {field} at frame {frame}, joint {joint} ({motion.skeleton.names[joint]!r})"
            )


def format_bvh(motion: BvhMotion, *, precision: int = 6) -> str:
    """BVH text of ``motion``; angles in degrees, ``precision`` decimals everywhere but the
    frame time, which is written exactly (shortest round-trip repr).

    Joints are written depth first; for a skeleton stored in another order the file's
    joint order (and that of a re-read motion) is the depth-first one.
    """
    if not (isinstance(precision, int) and 0 <= precision <= 15):
        raise ValueError(f"precision must be an integer in [0, 15], got {precision!r}")
    _check_finite(motion)
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

    def write_joint(j: int, depth: int) -> None:
        pad = "\t" * depth
        keyword = "ROOT" if j == 0 else "JOINT"
        out.write(f"{pad}{keyword} {skel.names[j]}\n{pad}{{\n")
        out.write(f"{pad}\tOFFSET {_format_row(offsets[j], precision)}\n")
        if motion.channels[j]:
            out.write(f"{pad}\tCHANNELS {len(motion.channels[j])} {' '.join(motion.channels[j])}\n")
        for c in children.get(j, []):
            write_joint(c, depth + 1)
        for off in sites.get(j, []):
            out.write(f"{pad}\tEnd Site\n{pad}\t{{\n{pad}\t\tOFFSET {_format_row(off, precision)}\n{pad}\t}}\n")
        out.write(f"{pad}}}\n")

    write_joint(0, 0)
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
