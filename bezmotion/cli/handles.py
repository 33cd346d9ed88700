"""``bezmotion inbetween``'s handles: parsed from the command line or a file, checked, made positions."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import jax.numpy as jnp
import numpy as np

from bezmotion._src.messages import listed, one_line
from bezmotion.handles import HANDLE_FARTHEST_CM, line_between_keys
from bezmotion.pipeline.model import HANDLE_SLOTS
from bezmotion.bmm.sampling import BezierMotionModel, Handles
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.ik.protocol import Pose, pose_fk
from bezmotion._src.structured_files import read_structured_file
from bezmotion.evaluation.window_figures import HANDLE_MISS_CM, ReachChains
from bezmotion.pipeline.authoring import RecognisedCharacter


@dataclasses.dataclass(frozen=True)
class HandleRequest:
    """A handle as the user wrote it.

    Attributes:
      joint: a characteristic joint's role or the skeleton's name for it.
      frame: frame of the in-between (0 = the start key).
      value: ``(x, y, z)`` cm: a position, or an offset when ``relative``.
      relative: ``value`` is an offset from the straight line between the keys.
      source: where it was written (``--handle …`` or ``--handles FILE: handle k``), for errors.
    """

    joint: str
    frame: int
    value: tuple[float, float, float]
    relative: bool
    source: str


_HANDLE = re.compile(r"^\s*(?P<joint>[^@=\s]+)\s*@\s*(?P<frame>[^=]*?)\s*=\s*(?P<plus>\+)?(?P<xyz>.*)$")
_HANDLE_FORM = "JOINT@FRAME=X,Y,Z (a position, cm) or JOINT@FRAME=+X,Y,Z (an offset from the straight line between the keys)"


def parse_handle(text: str) -> HandleRequest:
    """A ``--handle`` value, e.g. ``right_hand@12=40,150,80`` or ``right_hand@12=+0,25,0``.

    Raises:
      ValueError: not of that form (the message quotes it), a frame that is not a whole
        number or a coordinate that is not finite (the message names the value).
    """
    source = f"--handle {text}"
    match = _HANDLE.match(text)
    try:
        value = tuple(float(p) for p in match["xyz"].split(",")) if match else ()
    except ValueError:
        value = ()
    if len(value) != 3:
        raise ValueError(f"{source}: expected {_HANDLE_FORM}")
    if not re.fullmatch(r"[+-]?\d+", match["frame"]):
        try:
            float(match["frame"])
        except ValueError:
            raise ValueError(f"{source}: expected {_HANDLE_FORM}") from None
        raise ValueError(f"{source}: the frame must be a whole number, got {match['frame']}")
    if not np.isfinite(value).all():
        raise ValueError(f"{source}: the position must be finite, got {match['plus'] or ''}{match['xyz'].strip()}")
    return HandleRequest(match["joint"], int(match["frame"]), value, match["plus"] is not None, source)  # type: ignore[arg-type]


def _coordinates(value: Any) -> tuple[float, float, float] | None:
    """``value`` as three finite floats; ``None`` unless it is a list of three numbers, each
    finite as a float (a 400-digit integer is not)."""
    if not (isinstance(value, list) and len(value) == 3 and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)):
        return None
    try:
        xyz = tuple(float(v) for v in value)
    except OverflowError:
        return None
    return xyz if np.isfinite(xyz).all() else None  # type: ignore[return-value]


def read_handles_file(path: Path) -> list[HandleRequest]:
    """Handles from a JSON or TOML file (see the module docstring).

    Raises:
      FileNotFoundError: no such file.
      ValueError: a folder or other non-file; unreadable, not UTF-8, not valid JSON / TOML
        or nested too deep (:func:`~bezmotion._src.structured_files.read_structured_file`); or an
        entry without a joint, an integer frame and exactly one of ``position`` / ``offset``
        as three finite numbers (the message names the entry, shortened to one line).
    """
    if path.is_dir():
        raise ValueError(f"--handles {path}: is a folder, not a handles file")
    if not path.exists():
        raise FileNotFoundError(f"--handles {path}: no such file")
    if not path.is_file():  # a pipe or a device: reading it could wait forever
        raise ValueError(f"--handles {path}: not a regular file")
    try:
        data = read_structured_file(path)
    except (ValueError, OSError) as error:
        raise ValueError(f"--handles {path}: {one_line(error, 200)}") from None
    entries = data.get("handles") if isinstance(data, dict) else data
    if not isinstance(entries, list):
        raise ValueError(f'--handles {path}: expected a list of handles, or a table with a "handles" list')
    requests = []
    for i, entry in enumerate(entries):
        source = f"--handles {path}: handle {i}"
        kinds = [k for k in ("position", "offset") if isinstance(entry, dict) and k in entry]
        ok = isinstance(entry, dict) and isinstance(entry.get("joint"), str) and len(kinds) == 1
        frame = entry.get("frame") if ok else None
        value = _coordinates(entry[kinds[0]]) if ok else None
        if not (isinstance(frame, int) and not isinstance(frame, bool) and value is not None):
            raise ValueError(f'{source}: expected {{"joint": name, "frame": integer, "position" or "offset": [x, y, z]}}, got {one_line(repr(entry), 120)}')
        written = one_line(f"{entry['joint']}@{frame}", 60)  # the joint's name and frame as written, cut to fit a message
        requests.append(HandleRequest(entry["joint"], frame, value, kinds[0] == "offset", f"{source} ({written})"))
    return requests


def handle_role(request: HandleRequest, recognised: RecognisedCharacter) -> str:
    """The characteristic role of a handle's joint (a role name or the skeleton's name for one)."""
    if request.joint in CHARACTERISTIC_JOINTS:
        return request.joint
    names = recognised.character.skeleton.names
    own = {names[j]: role for role, j in zip(CHARACTERISTIC_JOINTS, recognised.character.characteristic)}
    if request.joint in own:
        return own[request.joint]
    raise ValueError(
        f"{request.source}: unknown joint {one_line(repr(request.joint), 60)}; handles go on {', '.join(CHARACTERISTIC_JOINTS)} "
        f"(this skeleton's {', '.join(own)})"
    )


def resolve_handles(
    requests: Sequence[HandleRequest],
    recognised: RecognisedCharacter,
    keys: Sequence[Pose],
    bmm: BezierMotionModel,
    *,
    key_frames: Sequence[int] | None = None,
) -> tuple[Handles, list[dict[str, Any]]]:
    """``(Handles, [{"joint", "frame", "position"}])`` of the requests: offsets made positions,
    every handle checked.

    Args:
      keys: the key poses: two for one window, more for a chain.
      key_frames: their frames, the first 0 (default every BMM window, ``bmm.config.num_frames − 1``: 30, apart).
    Returns:
      The handles ``(slots,)`` in the in-between's frames (counted from the first key),
      padded (``valid=False``) to a multiple of :data:`HANDLE_SLOTS` so that another count
      reuses the compiled in-between; the records as written.
    Raises:
      ValueError: an unknown joint, a frame outside the in-between or on a key of a chain,
        one the sampler refuses (:meth:`Handles.from_frames`), or a position farther than
        :data:`HANDLE_FARTHEST_CM` from the line between the keys, each naming the handle as
        it was written.
    """
    character = recognised.character
    key_frames = np.arange(len(keys)) * (bmm.config.num_frames - 1) if key_frames is None else np.asarray(key_frames)
    last = int(key_frames[-1])
    idx = np.asarray(character.characteristic)
    key_positions = np.stack([np.asarray(pose_fk(character, p)[1])[idx] for p in keys])  # (keys, 6, 3)
    records = []
    placed: dict[tuple[str, int], tuple[str, np.ndarray]] = {}  # (joint, frame) -> (handle as written, position)
    for r in requests:
        role = handle_role(r, recognised)
        if not 0 <= r.frame <= last:
            raise ValueError(one_line(f"{r.source}: frame {r.frame} is outside the in-between, frames 0…{last} (0 and {last} are the keys)"))
        if 0 < r.frame < last and r.frame in key_frames:
            raise ValueError(f"{r.source}: frame {r.frame} is a key of the chain (keys at {listed(key_frames.tolist())}); handles go between them")
        window = min(int(np.searchsorted(key_frames, r.frame, side="right")) - 1, len(keys) - 2)
        local = r.frame - int(key_frames[window])  # the frame in its window (0 and its span are the window's keys)
        shape = SimpleNamespace(num_frames=int(key_frames[window + 1] - key_frames[window]) + 1, num_joints=bmm.config.num_joints)  # what Handles.from_frames checks against
        line = line_between_keys(key_positions, CHARACTERISTIC_JOINTS.index(role), r.frame, key_frames)
        position = np.asarray(r.value, np.float64) + (line if r.relative else 0.0)
        dx, dy, dz = position - line
        away = float(np.hypot(np.hypot(dx, dy), dz))  # hypot: 1e200 cm squared would overflow
        if away > HANDLE_FARTHEST_CM:  # a slip of units or digits: no window's motion goes that far
            raise ValueError(
                f"{r.source}: {role} at frame {r.frame} lies {away / 100:.6g} m from the straight line between the keys' "
                f"{role} positions, farther than {HANDLE_FARTHEST_CM / 100:.0f} m (positions and offsets are in cm)"
            )
        earlier = placed.setdefault((role, r.frame), (r.source, position))
        if not np.array_equal(earlier[1], position):  # the sampler would refuse it too, naming neither
            shown = ", ".join(f"({', '.join(f'{x:.2f}' for x in p)})" for p in (earlier[1], position))
            raise ValueError(f"{r.source}: {role} at frame {r.frame} has another handle, {earlier[0]}, at a different position: {shown} cm")
        try:  # the sampler's own rules for handle frames, reported with the handle as written
            Handles.from_frames([role], [local], position[None], config=shape)
        except ValueError as error:
            raise ValueError(f"{r.source}: {error}") from None
        records.append({"joint": role, "frame": r.frame, "position": position.tolist()})
    return records_as_handles(records, slots=HANDLE_SLOTS * max(1, -(-len(records) // HANDLE_SLOTS))), records


def records_as_handles(records: Sequence[dict[str, Any]], slots: int | None = None) -> Handles:
    """The handle records (frames counted from the first key, as written) as one ``Handles``,
    padded with ``valid=False`` slots to ``slots`` (default: none)."""
    pad = (len(records) if slots is None else slots) - len(records)
    return Handles(
        joint=jnp.asarray([CHARACTERISTIC_JOINTS.index(r["joint"]) for r in records] + [0] * pad, jnp.int32),
        frame=jnp.asarray([r["frame"] for r in records] + [0] * pad, jnp.int32),
        position=jnp.asarray(np.reshape([r["position"] for r in records] + [[0.0] * 3] * pad, (-1, 3)), jnp.float32),
        valid=jnp.asarray([True] * len(records) + [False] * pad, bool),
    )


def _label(record: dict[str, Any]) -> str:
    return f"{record['joint']}@{record['frame']}"


def handle_conflicts(records: Sequence[dict[str, Any]], conflict: np.ndarray, reach: ReachChains) -> list[str]:
    """A warning for each pair of handles on one frame that no pose meets together:
    ``conflict`` ``(handles, handles)``, from
    :func:`~bezmotion.evaluation.window_figures.conflicting_handles`."""
    warnings = []
    for i, j in zip(*np.nonzero(np.triu(conflict, 1))):
        a, b = records[i], records[j]
        distance = float(np.linalg.norm(np.subtract(a["position"], b["position"])))
        allowed = float(reach.apart[CHARACTERISTIC_JOINTS.index(a["joint"]), CHARACTERISTIC_JOINTS.index(b["joint"])])
        warnings.append(
            f"handles {_label(a)} and {_label(b)} lie {distance:.1f} cm apart, farther than the skeleton reaches between "
            f"{a['joint']} and {b['joint']} ({allowed:.1f} cm): no pose meets both, and the IK will come as close to both as it can"
        )
    return warnings


def handle_misses(records: Sequence[dict[str, Any]], errors: Sequence[float], beyond: np.ndarray, paired: np.ndarray) -> list[str]:
    """A line for each handle missed by more than :data:`HANDLE_MISS_CM`, with why where it is
    known: ``beyond`` its limb's reach from where the IK put the limb's root
    (:func:`~bezmotion.evaluation.window_figures.beyond_reach`), or ``paired`` with another
    handle of its frame that no pose meets together with it (both ``(handles,)``)."""
    lines = []
    for record, error, out_of_reach, conflict in zip(records, errors, beyond, paired):
        if error > HANDLE_MISS_CM:
            why = (
                ": beyond the limb's reach from where the IK put its root" if out_of_reach
                else ": no pose meets it together with another handle on its frame" if conflict
                else ""
            )  # fmt: skip
            lines.append(f"handle {_label(record)} missed by {error:.1f} cm{why}")
    return lines


# ------------------------------------------------------------------------------- plan
