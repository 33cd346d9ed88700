"""Benchmark: a ``bezmotion inbetween`` run killed (SIGKILL) at any moment leaves the old output set or the new one.

    python benchmarks/cli_kills.py --kills 20 --out cli_kills.json

A first run writes a complete set into an ``--out`` folder (``inbetween.bvh``,
``inbetween.glb``, ``preview.gif``, ``summary.json``) beside a file of the user's own. Each
later run (another seed, so every file of its set differs) is killed by SIGKILL: half of
them at a random moment of the whole run, half a random moment after its staging folder
appears, over 1.1 times the first run's writing phase (from its staging folder to its exit:
while the set is written and moved into place, the moments that matter; some of those runs
finish first). Then the folder is looked at as the next run would first look at it
(:func:`~bezmotion._src.output_sets.existing_outputs`: what killed runs left is finished or
removed) and classified:

- ``"old"``: every file of the set is the previous set's, byte for byte;
- ``"new"``: every file differs from the previous set's and matches what the outputs record
  says this run wrote;
- ``"mixed"``: anything else (some old files beside new ones, a file missing).

``temporaries_left`` counts looks after which a staging folder or temporary file remained;
``user_file_lost`` counts looks after which the user's own file was gone or changed. Every
run, killed or not, is classified; a killed run's new set (when it got that far) is the old
set of the next.

Writes ``{"tried", "old", "new", "mixed", "temporaries_left", "user_file_lost", "runs": […], "machine": …}``.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _timing import machine_info, report
from bezmotion._src.io import file_sha256
from bezmotion._src.options import option, options, parse_options
from bezmotion._src.output_sets import OUTPUTS_RECORD, STAGING_PREFIX, existing_outputs
from bezmotion.assets import DEMO_CLIP

SET = ("inbetween.bvh", "inbetween.glb", "preview.gif", "summary.json")
USER_FILE = "notes.txt"


@options
class Options:
    kills: int = option(20, help="runs killed (default 20)")
    seed: int = option(0, help="the kill moments' seed")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")

    def __post_init__(self):
        if self.kills < 1:
            raise ValueError(f"--kills must be at least 1, got {self.kills}")


def command(folder: Path, seed: int) -> list[str]:
    """The run: the bundled clip, one handle, the rig IK and two DDIM steps (quick), a preview."""
    return [
        sys.executable, "-c", "import sys; from bezmotion.cli import main; sys.exit(main())", "inbetween", str(DEMO_CLIP), "--frames", "0", "30",
        "--handle", "right_hand@12=+0,25,0", "--ik", "rig", "--steps", "2", "--seed", str(seed), "--no-progress", "--out", f"{folder}/",
    ]  # fmt: skip


def hashes(folder: Path) -> dict[str, str | None]:
    return {name: file_sha256(folder / name) if (folder / name).is_file() else None for name in SET}


def classify(folder: Path, old: dict[str, str | None]) -> str:
    """``"old"``, ``"new"`` or ``"mixed"`` (module docstring), after the next run's first look."""
    existing_outputs(folder, SET, "")  # what the next run does first: finish or clear what a killed one left
    now = hashes(folder)
    if now == old:
        return "old"
    try:
        record = json.loads((folder / OUTPUTS_RECORD).read_text(encoding="utf-8"))["files"]
    except (OSError, ValueError, KeyError):
        return "mixed"
    recorded = {name: record.get(name, {}).get("sha256") for name in SET}
    if all(now[n] is not None and now[n] != old[n] and now[n] == recorded[n] for n in SET):
        return "new"
    return "mixed"


def leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(STAGING_PREFIX) or p.name.endswith(".tmp")]


def start(folder: Path, seed: int) -> subprocess.Popen:
    return subprocess.Popen(command(folder, seed), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def until_staging(folder: Path, process: subprocess.Popen) -> None:
    """Wait until the run's staging folder appears (or the run ends)."""
    while process.poll() is None and not any(p.name.startswith(STAGING_PREFIX) for p in folder.iterdir()):
        time.sleep(0.005)


def run_killed(folder: Path, seed: int, rng: random.Random, at_write: bool, whole_run_s: float, write_s: float) -> dict:
    """One run, killed at a random moment (of the whole run, or of its writing); what it left."""
    process = start(folder, seed)
    started = time.monotonic()
    if at_write:
        until_staging(folder, process)
    time.sleep(rng.uniform(0.0, 1.1 * write_s if at_write else whole_run_s))
    killed = process.poll() is None
    if killed:
        os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    return {"seed": seed, "at_write": at_write, "killed": killed, "after_s": round(time.monotonic() - started, 3)}


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="bezmotion-kills-") as tmp:
        folder = Path(tmp) / "take"
        folder.mkdir()
        (folder / USER_FILE).write_text("the user's own notes\n")
        started = time.monotonic()
        first = start(folder, 0)
        until_staging(folder, first)
        writing = time.monotonic()
        if first.wait() != 0:
            raise SystemExit(f"the first run failed: {' '.join(command(folder, 0))}")
        whole_run_s, write_s = time.monotonic() - started, time.monotonic() - writing
        old = hashes(folder)
        runs = []
        for k in range(1, args.kills + 1):
            run = run_killed(folder, k, rng, at_write=k % 2 == 0, whole_run_s=whole_run_s, write_s=write_s)
            run["outcome"] = classify(folder, old)
            run["left"] = leftovers(folder)
            run["user_file_kept"] = (folder / USER_FILE).read_text() == "the user's own notes\n"
            runs.append(run)
            print(json.dumps(run), flush=True)
            old = hashes(folder)
    counts = {key: sum(r["outcome"] == key for r in runs) for key in ("old", "new", "mixed")}
    result = {
        "tried": len(runs), **counts,
        "killed": sum(r["killed"] for r in runs),
        "temporaries_left": sum(bool(r["left"]) for r in runs),
        "user_file_lost": sum(not r["user_file_kept"] for r in runs),
        "whole_run_s": round(whole_run_s, 2), "write_s": round(write_s, 3), "runs": runs, "machine": machine_info(),
    }  # fmt: skip
    summary = {k: v for k, v in result.items() if k not in ("runs", "machine")}
    return report(result, summary, args.out)


if __name__ == "__main__":
    main()
