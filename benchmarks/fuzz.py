"""Fuzzing: mutated input files through the BVH reader, the handles reader and the command.

Every mutant either reads (or the command runs) into finite values, or is refused with a
clear error: a ``ValueError`` or ``FileNotFoundError`` (the command: exit status 2) whose
message is one line of about :data:`~bezmotion._src.messages.MESSAGE_CHARS` characters
besides the file's name, naming the file. Anything else is counted, with examples to
reproduce it.

- ``--target read_bvh``: mutants of the bundled clip through :func:`bezmotion.data.bvh.read_bvh`,
  in this process.
- ``--target handles``: mutants of handles files (JSON and TOML; now and then a folder or a
  missing file instead) through the command's handles reader
  (:func:`bezmotion.cli.handles.read_handles_file`) and its checks against the bundled clip's
  keys and the bundled BMM (``handle_role``, ``resolve_handles``, which builds the sampler's
  ``Handles``).
- ``--target cli``: mutants of the bundled clip cut to 31 frames through ``bezmotion inbetween
  MUTANT.bvh --frames 0 30 --out DIR --no-preview --no-progress --ik rig --steps 2``, in this
  process (:func:`bezmotion.cli.main`), each into a folder of its own.

Outcomes (the JSON's counts): ``accepted_finite`` (read, or the command exited 0 and its BVH
reads back), ``clear_error``, ``traceback`` (any other exception or exit, an error message
over length, on several lines or not naming the file, or an accepted mutant with a value
that is not finite), ``hang`` (past ``--limit-s`` seconds), and for the command ``files_left``
(a failed run that left files in its folder). ``examples`` lists a few of each bad outcome
with the mutations that made them; ``--start K --mutants 1 --keep DIR`` makes mutant K again
and keeps its file.

    python benchmarks/fuzz.py --target read_bvh --mutants 10000 --out results/fuzz_read_bvh.json
    python benchmarks/fuzz.py --target handles --mutants 3000 --out results/fuzz_handles.json
    python benchmarks/fuzz.py --target cli --mutants 200 --out results/fuzz_cli.json

Mutant ``k`` of a target is made from ``random.Random(f"{seed}:{target}:{k}")`` alone, so a
run is reproducible and any mutant can be made again on its own. The mutations take their
choices from a ``pick(n) -> 0…n-1`` function, which the property tests
(``tests/test_fuzz.py``) draw from hypothesis instead.
"""

from __future__ import annotations

import contextlib
import io
import json
import random
import re
import signal
import shutil
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import jax
import numpy as np

from _timing import machine_info, write_json
from bezmotion._src.messages import MESSAGE_CHARS, one_line
from bezmotion._src.options import option, options, parse_options
from bezmotion.assets import DEMO_CLIP

Pick = Callable[[int], int]
"""A choice among ``n``: returns 0…n-1 (``random.Random.randrange``, or drawn by hypothesis)."""

Mutation = Callable[[bytes, Pick], bytes]

NASTY_NUMBERS = (
    "1e300", "-1e308", "1e-320", "4.9e-324", "1e400", "-1e400", "nan", "-nan", "NaN", "inf", "-inf", "Infinity",
    "0", "-0", "-1", "1e5", "1e6", "1e7", "1e9", "1e17", "99999999999999999999", "1" + "0" * 400, "0.0333333",
    "0x1F", "1_000", "١٢", "1e", ".", "+", "--1", "1,5", "", "3.", "-.5e-3",
)  # fmt: skip
"""Numbers a mutant puts in place of one: beyond every limit, below every resolution, not
finite, not quite numbers, and a few ordinary ones."""

_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
CLEAR_EXCEPTIONS = (ValueError, FileNotFoundError)
CLI_FRAMES = 31  # the command's mutants: one window of the BMM and no more, so an accepted one runs fast


class Hang(BaseException):
    """A mutant ran past its time limit (a ``BaseException``, so no ``except Exception`` keeps it)."""


# ----------------------------------------------------------------------------- mutations


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def _one_of(items: Sequence[Any], pick: Pick) -> Any:
    return items[pick(len(items))]


def flip_byte(data: bytes, pick: Pick) -> bytes:
    """One byte replaced by another (any of the 256)."""
    if not data:
        return bytes([pick(256)])
    at = pick(len(data))
    return data[:at] + bytes([pick(256)]) + data[at + 1 :]


def delete_lines(data: bytes, pick: Pick) -> bytes:
    """One to four lines removed."""
    lines = _lines(data)
    at = pick(len(lines))
    return b"\n".join(lines[:at] + lines[at + 1 + pick(4) :])


def duplicate_line(data: bytes, pick: Pick) -> bytes:
    """A line repeated one to three times."""
    lines = _lines(data)
    at = pick(len(lines))
    return b"\n".join(lines[: at + 1] + [lines[at]] * (1 + pick(3)) + lines[at + 1 :])


def swap_lines(data: bytes, pick: Pick) -> bytes:
    """Two lines swapped."""
    lines = _lines(data)
    a, b = pick(len(lines)), pick(len(lines))
    lines[a], lines[b] = lines[b], lines[a]
    return b"\n".join(lines)


def replace_number(data: bytes, pick: Pick) -> bytes:
    """A number replaced by one of :data:`NASTY_NUMBERS`, or scaled by a huge or tiny power of ten."""
    numbers = list(_NUMBER.finditer(data))
    if not numbers:
        return data
    match = _one_of(numbers, pick)
    if pick(4) == 0:
        new = f"{match.group().decode()}e{_one_of((-400, -320, -30, 8, 30, 300, 400), pick)}".encode()
    else:
        new = _one_of(NASTY_NUMBERS, pick).encode()
    return data[: match.start()] + new + data[match.end() :]


def truncate(data: bytes, pick: Pick) -> bytes:
    """The file cut short anywhere, mid-line or mid-number."""
    return data[: pick(len(data) + 1)]


def line_endings(data: bytes, pick: Pick) -> bytes:
    """CR (old Mac), CRLF, or a mix of them."""
    kind = pick(3)
    if kind == 2:
        return b"".join(line + _one_of((b"\r", b"\r\n", b"\n"), pick) for line in _lines(data))
    return data.replace(b"\n", (b"\r", b"\r\n")[kind])


def emptied(data: bytes, pick: Pick) -> bytes:
    """Nothing, or nothing but blank lines."""
    return _one_of((b"", b"\n", b"\r", b"\r\n\r\n", b"   \n\t\n", b"\xef\xbb\xbf"), pick)


def junk_line(data: bytes, pick: Pick) -> bytes:
    """A line of random bytes, a NUL, a byte-order mark or a 10,000-character token put in."""
    lines = _lines(data)
    junk = _one_of((bytes(pick(256) for _ in range(1 + pick(40))), b"\x00", b"\xef\xbb\xbf", b"x" * 10_000, b"9" * 5_000), pick)
    at = pick(len(lines) + 1)
    if pick(2):  # inside a line rather than one of its own
        line = lines[min(at, len(lines) - 1)]
        cut = pick(len(line) + 1)
        lines[min(at, len(lines) - 1)] = line[:cut] + junk + line[cut:]
        return b"\n".join(lines)
    return b"\n".join(lines[:at] + [junk] + lines[at:])


def long_file(data: bytes, pick: Pick) -> bytes:
    """The text twice, or its last part repeated (many more motion rows or entries)."""
    lines = _lines(data)
    return data + b"\n" + b"\n".join(lines[-(1 + pick(len(lines))) :] * (1 + pick(20)))


COMMON_MUTATIONS: tuple[Mutation, ...] = (
    flip_byte, delete_lines, duplicate_line, swap_lines, replace_number, replace_number, truncate, line_endings,
    emptied, junk_line, long_file,
)  # fmt: skip

_DEPTHS = (2, 40, 255, 256, 257, 1_100, 5_000, 100_000)


def bvh_deep_nesting(data: bytes, pick: Pick) -> bytes:
    """A chain of joints nested thousands deep put in after a joint's CHANNELS line, with no
    channels (the motion rows still fit) or with rotation channels (they do not)."""
    lines = _lines(data)
    places = [i for i, line in enumerate(lines) if line.strip().upper().startswith(b"CHANNELS")] or [0]
    at = _one_of(places, pick) + 1
    depth = min(_one_of(_DEPTHS, pick), 6_000)
    channels = _one_of((b"CHANNELS 0", b"CHANNELS 3 Zrotation Xrotation Yrotation"), pick)
    opened = [b"JOINT fuzz%d\n{\nOFFSET 0 1 0\n%s" % (i, channels) for i in range(depth)]
    chain = b"\n".join(opened) + b"\nEnd Site\n{\nOFFSET 0 1 0\n}\n" + b"}\n" * depth
    return b"\n".join(lines[:at] + [chain] + lines[at:])


def bvh_many_joints(data: bytes, pick: Pick) -> bytes:
    """Hundreds or thousands of sibling joints (no channels) under one joint."""
    lines = _lines(data)
    places = [i for i, line in enumerate(lines) if line.strip().upper().startswith(b"CHANNELS")] or [0]
    at = _one_of(places, pick) + 1
    count = _one_of((100, 4_070, 4_075, 5_000, 20_000), pick)
    siblings = b"\n".join(b"JOINT wide%d\n{\nOFFSET 1 0 0\nCHANNELS 0\n}" % i for i in range(count))
    return b"\n".join(lines[:at] + [siblings] + lines[at:])


_BVH_WORDS = (b"HIERARCHY", b"ROOT", b"JOINT", b"End Site", b"End", b"{", b"}", b"OFFSET", b"CHANNELS", b"MOTION", b"Frames:", b"Frame Time:")


def bvh_keyword(data: bytes, pick: Pick) -> bytes:
    """A keyword, brace or channel name swapped for another, or a line's first word dropped."""
    lines = _lines(data)
    at = pick(len(lines))
    words = lines[at].split()
    if not words:
        return data
    if pick(3) == 0:
        words = words[1:]
    else:
        words[pick(len(words))] = _one_of(_BVH_WORDS + (b"Xposition", b"Wrotation", b"joint", b"hierarchy"), pick)
    lines[at] = b" ".join(words)
    return b"\n".join(lines)


def bvh_header_numbers(data: bytes, pick: Pick) -> bytes:
    """The ``Frames:`` count, the ``Frame Time`` or a CHANNELS count made something else."""
    lines = _lines(data)
    places = [i for i, line in enumerate(lines) if line.strip().upper().startswith((b"FRAMES", b"FRAME TIME", b"CHANNELS"))]
    if not places:
        return data
    at = _one_of(places, pick)
    value = _one_of((b"0", b"-1", b"1", b"7", b"1000000000000", b"1" + b"0" * 5000, b"1e3", b"nan", b"0.5"), pick)
    if b":" in lines[at]:
        lines[at] = lines[at].partition(b":")[0] + b": " + value
    else:
        words = lines[at].split()
        lines[at] = b" ".join([words[0], value, *words[2:]])
    return b"\n".join(lines)


BVH_MUTATIONS: tuple[Mutation, ...] = COMMON_MUTATIONS + (bvh_deep_nesting, bvh_many_joints, bvh_keyword, bvh_keyword, bvh_header_numbers)


def handles_deep_nesting(data: bytes, pick: Pick) -> bytes:
    """The file's value (or one entry's position) nested in thousands of lists or tables,
    or, in TOML, a table thousands of dotted keys deep."""
    depth = _one_of(_DEPTHS, pick)
    kind = pick(4)
    if data.lstrip().startswith(b"[["):  # TOML
        if kind == 0:
            return data + b"\n[" + b".".join(b"k%d" % i for i in range(min(depth, 20_000))) + b"]\nx = 1\n"
        return data + b"\ndeep = " + b"[" * depth + b"]" * depth + b"\n"
    if kind == 0:
        return b'{"a":' * depth + data + b"}" * depth
    if kind == 1:
        return data.replace(b"[", b"[" * depth, 1)  # left open: invalid, but the parser recurses first
    return data.replace(b'"position": [', b'"position": ' + b"[" * depth + b"[", 1).replace(b"]", b"]" + b"]" * depth, 1)


def handles_values(data: bytes, pick: Pick) -> bytes:
    """A key renamed, or a value made a string, a boolean, null, a huge integer or a long string."""
    keys = (b'"joint"', b'"frame"', b'"position"', b'"offset"', b'"handles"', b"joint", b"frame", b"position", b"offset")
    present = [k for k in keys if k in data]
    if not present:
        return data
    key = _one_of(present, pick)
    if pick(2):
        return data.replace(key, _one_of((b'"jiont"', b'"frame"', b'"offset"', b'"position"', b"x", b'""'), pick), 1)
    start = data.index(key) + len(key)
    end = min([i for i in (data.find(b",", start), data.find(b"\n", start), data.find(b"}", start)) if i >= 0], default=len(data))
    value = _one_of((b': "12"', b": true", b": null", b": 1" + b"0" * 400, b': "' + b"x" * 20_000 + b'"', b": []", b": {}", b" = 1e999"), pick)
    return data[:start] + value + data[end:]


HANDLES_MUTATIONS: tuple[Mutation, ...] = COMMON_MUTATIONS + (handles_deep_nesting, handles_deep_nesting, handles_values, handles_values)

HANDLES_FILES = {
    "handles.json": b'[{"joint": "right_hand", "frame": 12, "position": [40.0, 150.0, 80.0]},\n'
    b' {"joint": "left_foot", "frame": 18, "offset": [0, 10, 0]}]\n',
    "wrapped.json": b'{"handles": [\n  {"joint": "head", "frame": 6, "offset": [0, 5, 0]},\n  {"joint": "Hand_R", "frame": 20, "offset": [0, 20, 0]}\n]}\n',
    "handles.toml": b'[[handles]]\njoint = "left_foot"\nframe = 18\noffset = [0, 10, 0]\n\n[[handles]]\njoint = "hips"\nframe = 12\nposition = [0.5, 90, 3]\n',
}
"""The handles files mutated: a list as Blender exports it, a table with a ``handles`` list, TOML."""


def mutate(data: bytes, pick: Pick, mutations: Sequence[Mutation], most: int = 3) -> tuple[bytes, list[str]]:
    """``data`` after one to ``most`` mutations chosen by ``pick``, and their names."""
    names = []
    for _ in range(1 + pick(most)):
        mutation = _one_of(mutations, pick)
        data = mutation(data, pick)
        names.append(mutation.__name__)
    return data, names


# ----------------------------------------------------------------------------- outcomes


def unclear(message: str, path: Path) -> str | None:
    """Why ``message`` is not a clear error about ``path``, or ``None`` when it is one: one
    line, at most :data:`MESSAGE_CHARS` characters besides the file's name, naming the file."""
    if "\n" in message.strip():
        return f"an error on {message.strip().count(chr(10)) + 1} lines: {one_line(message, 200)}"
    if len(message) > MESSAGE_CHARS + len(str(path)):
        return f"an error of {len(message)} characters: {one_line(message, 200)}"
    if str(path) not in message:
        return f"an error not naming the file: {one_line(message, 200)}"
    return None


def _exception(error: BaseException, path: Path) -> tuple[str, str | None]:
    """The outcome of an exception: a clear error, or a traceback with why."""
    if isinstance(error, CLEAR_EXCEPTIONS):
        why = unclear(str(error), path)
        if why is None:
            return "clear_error", None
        return "traceback", f"{type(error).__name__}: {why}"
    return "traceback", f"{type(error).__name__}: {one_line(error, 200)}"


def read_bvh_outcome(path: Path) -> tuple[str, str | None]:
    """``(outcome, why)`` of :func:`~bezmotion.data.bvh.read_bvh` on ``path``."""
    from bezmotion.data.bvh import read_bvh

    try:
        motion = read_bvh(path)
    except Exception as error:  # noqa: BLE001 — every exception is classified
        return _exception(error, path)
    arrays = (motion.quat_local, motion.pos_local, np.asarray(motion.skeleton.offsets), np.asarray([o for _, o in motion.end_sites]), motion.frame_time)
    if all(np.isfinite(a).all() for a in arrays):
        return "accepted_finite", None
    return "traceback", "accepted with a value that is not finite"


def handles_outcome(path: Path, plan: Any = None) -> tuple[str, str | None]:
    """``(outcome, why)`` of reading the handles file ``path`` as ``bezmotion inbetween
    --handles`` does and, given the command's ``plan`` (of the clip's keys and the BMM),
    checking them as it does."""
    from bezmotion.cli.handles import handle_role, read_handles_file, resolve_handles

    try:
        requests = read_handles_file(path)
        values = [r.value for r in requests]
        if plan is not None:
            for r in requests:
                handle_role(r, plan.recognised)
            handles, records = resolve_handles(requests, plan.recognised, plan.keys, plan.bmm)
            values += [r["position"] for r in records] + [np.asarray(handles.position)]
    except Exception as error:  # noqa: BLE001
        return _exception(error, path)
    if all(np.isfinite(v).all() for v in values):
        return "accepted_finite", None
    return "traceback", "accepted with a value that is not finite"


def cli_outcome(path: Path, out: Path, extra: Sequence[str]) -> tuple[str, str | None]:
    """``(outcome, why)`` of ``bezmotion inbetween path --frames 0 30 --out out …extra``;
    ``files_left`` when it failed yet left files in ``out``'s folder."""
    from bezmotion.cli import main
    from bezmotion.data.bvh import read_bvh

    argv = ["inbetween", str(path), "--frames", "0", str(CLI_FRAMES - 1), "--out", str(out), "--no-preview", "--no-progress", *extra]
    stdout, stderr = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            try:
                code = main(argv)
            except SystemExit as exit_:  # argparse's own errors
                code = exit_.code
    except Exception as error:  # noqa: BLE001
        outcome = ("traceback", f"{type(error).__name__}: {one_line(error, 200)}")
    else:
        lines = [line for line in stderr.getvalue().splitlines() if line.strip()]
        error_line = lines[-1].removeprefix("bezmotion: error: ") if lines and lines[-1].startswith("bezmotion: error: ") else None
        if code == 0:
            try:
                written = [read_bvh(f) for f in sorted(out.glob("*.bvh"))] if out.is_dir() else [read_bvh(out)]
                outcome = ("accepted_finite", None) if written else ("traceback", "exit 0 but no BVH written")
            except (ValueError, OSError) as error:
                outcome = ("traceback", f"exit 0 but the BVH written does not read back: {one_line(error, 200)}")
        elif code == 2 and error_line is not None:
            why = unclear(error_line, path)
            outcome = ("clear_error", None) if why is None else ("traceback", why)
        else:
            outcome = ("traceback", f"exit {code}: {one_line(stderr.getvalue()[-400:], 200)}")
    left = sorted(p.name for p in path.parent.iterdir() if p != path)
    if outcome[0] != "accepted_finite" and left:
        return "files_left", f"{outcome[0]}, leaving {', '.join(left[:5])}"
    return outcome


# ----------------------------------------------------------------------------- the run


@options
class Options:
    target: str = option(choices=("read_bvh", "handles", "cli"), help="what the mutants go through")
    mutants: int = option(1000, help="how many mutants (default 1000)")
    start: int = option(0, help="the first mutant's number (with --mutants 1: make mutant K again)")
    seed: int = option(0, help="the seed every mutant's choices derive from (default 0)")
    limit_s: float | None = option(None, help="seconds a mutant may take before it counts as a hang (default 10; cli: 120)")
    ik: str = option("rig", help="cli: the --ik of the command (default rig: any skeleton, fastest)")
    steps: int = option(2, help="cli: DDIM steps (default 2)")
    examples: int = option(5, help="examples kept of each bad outcome (default 5)")
    keep: Path | None = option(None, help="copy each bad mutant's file into this folder")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def timed(limit_s: float, fn: Callable[[], tuple[str, str | None]]) -> tuple[str, str | None]:
    """``fn()``, or ``("hang", …)`` past ``limit_s`` seconds (a timer signal: this thread must be the main one)."""

    def expire(signum, frame):
        raise Hang

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, limit_s)
    try:
        return fn()
    except Hang:
        return "hang", f"past {limit_s:g} s"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


CLEAR_EVERY = 100
"""The ``cli`` target clears JAX's compiled programs every so many mutants."""


def _cli_clip() -> bytes:
    """The bundled clip cut to its first :data:`CLI_FRAMES` frames, as written."""
    lines = DEMO_CLIP.read_bytes().split(b"\n")
    frames_at = next(i for i, line in enumerate(lines) if line.startswith(b"Frames:"))
    return b"\n".join(lines[:frames_at] + [b"Frames:\t%d" % CLI_FRAMES] + lines[frames_at + 1 : frames_at + 2 + CLI_FRAMES]) + b"\n"


def _handles_plan(out: Path) -> Any:
    """The command's plan for the bundled clip's frames 0 and 30 (the keys and the BMM the
    handles are checked against), to write into the empty folder ``out`` (it writes nothing)."""
    from bezmotion.cli.plan import InbetweenCommand, plan

    return plan(parse_options(InbetweenCommand, [str(DEMO_CLIP), "--frames", "0", "30", "--ik", "rig", "--no-progress", "--out", str(out)]))


def run(args: Options) -> dict[str, Any]:
    """Make and try ``args.mutants`` mutants; the counts, examples and timing."""
    target: Literal["read_bvh", "handles", "cli"] = args.target  # type: ignore[assignment]
    limit_s = args.limit_s if args.limit_s is not None else (120.0 if target == "cli" else 10.0)
    extra = ["--ik", args.ik, "--steps", str(args.steps)]
    counts: Counter[str] = Counter()
    examples: dict[str, list[dict[str, Any]]] = {}
    bases = {"read_bvh": {"clip.bvh": DEMO_CLIP.read_bytes()}, "cli": {"clip.bvh": _cli_clip()}, "handles": HANDLES_FILES}[target]
    mutations = HANDLES_MUTATIONS if target == "handles" else BVH_MUTATIONS
    with tempfile.TemporaryDirectory(prefix="fuzz_") as tmp:
        root = Path(tmp)
        plan = _handles_plan(root / "plan") if target == "handles" else None

        def attempt(k: int, data: bytes | None, name: str, shape: str = "file") -> tuple[str, str | None]:
            folder = root / str(k)
            folder.mkdir()
            path = folder / name
            if shape == "folder":
                path.mkdir()
            elif shape == "file":
                path.write_bytes(data)
            if target == "read_bvh":
                return timed(limit_s, lambda: read_bvh_outcome(path))
            if target == "handles":
                return timed(limit_s, lambda: handles_outcome(path, plan))
            if k % CLEAR_EVERY == 0:
                # Each accepted skeleton compiles its own programs; a thousand mutants' kept in
                # one process exhaust the kernel's memory maps.
                jax.clear_caches()
            return timed(limit_s, lambda: cli_outcome(path, folder / "out", extra))

        # Each base once first, outside the count: it must be accepted, and the compiling is done.
        for name, data in bases.items():
            warm = attempt(-1 - list(bases).index(name), data, name)
            if warm[0] != "accepted_finite":
                raise SystemExit(f"the unmutated {name} is not accepted: {warm}")
        started = time.perf_counter()
        for k in range(args.start, args.start + args.mutants):
            rng = random.Random(f"{args.seed}:{target}:{k}")
            name = rng.choice(sorted(bases))
            shape = "file" if target != "handles" else rng.choice(("file",) * 18 + ("folder", "missing"))
            data, applied = mutate(bases[name], rng.randrange, mutations)
            outcome, why = attempt(k, data, name, shape)
            counts[outcome] += 1
            if outcome not in ("accepted_finite", "clear_error") and len(examples.setdefault(outcome, [])) < args.examples:
                examples[outcome].append({"mutant": k, "base": name, "shape": shape, "mutations": applied, "bytes": len(data), "why": why})
                if args.keep is not None:
                    args.keep.mkdir(parents=True, exist_ok=True)
                    (args.keep / f"{target}_{k}_{name}").write_bytes(data)
            shutil.rmtree(root / str(k), ignore_errors=True)
            if (k - args.start + 1) % 500 == 0:
                print(f"{k - args.start + 1} mutants: {dict(counts)}", file=sys.stderr, flush=True)
        seconds = time.perf_counter() - started
    return {
        "target": target,
        "tried": args.mutants,
        **{key: counts[key] for key in ("clear_error", "accepted_finite", "traceback", "hang", "files_left")},
        "examples": examples,
        "seed": args.seed,
        "first_mutant": args.start,
        "limit_s": limit_s,
        "seconds": seconds,
        "seconds_per_mutant": seconds / max(args.mutants, 1),
        **({"cli_arguments": extra} if target == "cli" else {}),
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse_options(Options, argv, description=__doc__)
    result = run(args) | {"benchmark": "fuzz", "command": " ".join(sys.argv), "machine": machine_info()}
    print(json.dumps({k: v for k, v in result.items() if k not in ("machine", "examples")}, indent=2))
    for outcome, found in result["examples"].items():
        for example in found:
            print(f"{outcome}: {json.dumps(example)}")
    if args.out:
        write_json(args.out, result)
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
