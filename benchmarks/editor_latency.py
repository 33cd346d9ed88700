"""Benchmark: how live the editor feels, a recorded editing session driven through its API.

The bundled clip and models (``EditSession.open``, the IK ``auto`` picks: the exact IK on
the learned IK's poses), one 31-frame window, a right-hand handle at frame 12 and a left-foot
pin at frame 20. The recording drags the hand through ``--waypoints`` (cm from where its
curve was), ``--moves`` gizmo moves per drag eased in and out, and releases after each drag.

- ``body_update_ms``: one :meth:`EditSession.drag`, the curves re-projected onto the handle
  (no diffusion) and the body solved by the exact IK from the previous move's (median, p95).
- ``resample_ms``: one :meth:`EditSession.release`, a full resample through the handles.
- ``undo_ms``: one :meth:`EditSession.undo` back over a release (its view kept).
- ``first_paint_s``: from starting ``bezmotion edit`` on the bundled clip to its page drawn
  in a browser (the clip's body; headless Debian chromium through playwright, opened before
  the command; without them, to the printed address: ``first_paint_to`` says which), with
  XLA's compilation cache warm: the command run twice on a fresh cache folder, the second
  run timed. ``first_inbetween_s``: to the in-between drawn too (the page's status no longer
  says it is sampling). ``*_cold_s``: the first run (an empty cache: a first start).
- ``open_s`` and ``compile_s``, in this process (no persistent cache): opening the session
  (reading the clip, loading the models), then the compilations: the in-between (the first
  view: compiling and one sample) and the drag (:meth:`EditSession.warm_up`).
- ``handles_error_max_cm``: the farthest any handle lay from its joint after any move or release.

Timings are steady state (everything compiled first), with the machine and its load average
before and after (another process on the cores slows every figure).

    python benchmarks/editor_latency.py --out editor_latency.json
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _timing import machine_info, report
from bezmotion._src.options import option, options, parse_options
from bezmotion.assets import DEMO_CLIP
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.editor import EditSession

WAYPOINTS = ((0.0, 15.0, 0.0), (0.0, 2.0, -3.0), (0.0, 10.0, 12.0), (8.0, 4.0, 0.0), (0.0, -6.0, 6.0), (3.0, 1.0, 2.0))
"""Where the recorded drags take the hand, cm from its curve before the first (each a drag;
each round of them 1 cm higher than the one before, so that no release comes back to a
state the session has sampled, whose view it would show at once)."""


@options
class Options:
    moves: int = option(30, help="gizmo moves per drag (a second of dragging at 30 Hz)")
    rounds: int = option(2, help="times the recorded drags are played")
    ik: str = option("auto", help="the session's IK (EditSession.open's ik=)")
    no_command: bool = option(False, help="skip the first paint of the command (two runs of bezmotion edit)")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def _stats(values_s: list[float]) -> dict[str, float]:
    ms = 1e3 * np.asarray(values_s)
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "max": float(ms.max()), "count": len(ms)}


CHROMIUM = Path("/usr/bin/chromium")
COMMAND = [sys.executable, "-c", "import sys; from bezmotion.cli import main; sys.exit(main())", "edit", str(DEMO_CLIP), "--port", "0", "--no-browser"]
"""``bezmotion edit`` on the bundled clip, from this interpreter."""
ADDRESS = re.compile(r"open (http://\S+)")
DRAWN_SPREAD = 0.02  # the canvas's RGB standard deviation (0–1) once the body is drawn; blank: ~0


def _canvas_spread(page) -> float:
    import matplotlib.image

    png = page.locator("canvas").first.screenshot()
    return float(matplotlib.image.imread(io.BytesIO(png), format="png")[..., :3].std())


def command_first_paint(cache: Path, out: Path, browser=None, timeout_s: float = 600.0) -> dict:
    """Seconds from starting the command (``cache``: its XLA cache folder) to its printed
    address and, with ``browser`` (playwright's), to the body drawn in a new page."""
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(cache), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0", "PYTHONUNBUFFERED": "1"}
    started = time.perf_counter()
    process = subprocess.Popen([*COMMAND, "--out", str(out)], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        url, seen = None, []
        for line in process.stdout:
            seen.append(line)
            if match := ADDRESS.search(line):
                url = match.group(1)
                break
        if url is None:
            raise RuntimeError("bezmotion edit printed no address:\n" + "".join(seen[-20:]))
        result = {"address_s": time.perf_counter() - started}
        if browser is not None:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(url)
            page.wait_for_selector("canvas", timeout=timeout_s * 1000)
            while _canvas_spread(page) < DRAWN_SPREAD:
                if time.perf_counter() - started > timeout_s:
                    raise RuntimeError(f"the editor's page drew nothing in {timeout_s:.0f} s")
                page.wait_for_timeout(50)
            result["paint_s"] = time.perf_counter() - started
            page.get_by_text("every handle met").wait_for(timeout=timeout_s * 1000)
            result["inbetween_s"] = time.perf_counter() - started
            page.close()
        return result
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()


def first_paints() -> dict:
    """The command's first paint, cold then warm (one fresh XLA cache folder for both)."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        sync_playwright = None
    with tempfile.TemporaryDirectory() as folder, contextlib.ExitStack() as stack:
        browser = None
        if sync_playwright is not None and CHROMIUM.exists():
            playwright = stack.enter_context(sync_playwright())
            browser = playwright.chromium.launch(
                executable_path=str(CHROMIUM), args=["--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
            )
            stack.callback(browser.close)
        cold = command_first_paint(Path(folder) / "xla", Path(folder) / "out", browser)
        warm = command_first_paint(Path(folder) / "xla", Path(folder) / "out", browser)
    key = "paint_s" if browser is not None else "address_s"
    return {
        "first_paint_s": warm[key], "first_paint_cold_s": cold[key],
        "first_inbetween_s": warm.get("inbetween_s"), "first_inbetween_cold_s": cold.get("inbetween_s"),
        "first_paint_to": "the body drawn in headless chromium" if browser is not None else "the printed address (no chromium/playwright)",
        "command_runs": {"cold": cold, "warm": warm},
    }  # fmt: skip


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        session = EditSession.open(DEMO_CLIP, out, ik=args.ik)
        opened = time.perf_counter() - t0
        first = session.view
        first_paint = time.perf_counter() - t0
        hand_role = CHARACTERISTIC_JOINTS.index("right_hand")
        origin = first.positions[12, hand_role].copy()
        hand = session.add_handle("right_hand", 12)
        session.add_handle("left_foot", 20)
        t = time.perf_counter()
        session.warm_up()
        drag_compile = time.perf_counter() - t
        body, resample, undo, errors, released = [], [], [], [], set()
        for round_ in range(args.rounds):
            for waypoint in WAYPOINTS:
                begin, end = np.asarray(session.state.handles[0].position), origin + np.asarray(waypoint) + [0.0, round_, 0.0]
                for k in range(1, args.moves + 1):
                    s = k / args.moves
                    position = begin + (3 * s**2 - 2 * s**3) * (end - begin)  # eased in and out, as a hand moves
                    t = time.perf_counter()
                    view = session.drag(hand, position)
                    body.append(time.perf_counter() - t)
                    errors.append(max(view.handle_errors.values()))
                t = time.perf_counter()
                view = session.release()
                resample.append(time.perf_counter() - t)
                released.add(session.state)
                errors.append(max(view.handle_errors.values()))
            t = time.perf_counter()
            session.undo()
            undo.append(time.perf_counter() - t)
            session.redo()
    result = {
        "benchmark": "editor_latency",
        "window_frames": session.frames,
        "ik": session.state.ik,
        "steps": session.state.options.steps,
        "foot_lock": session.state.options.foot_lock,
        "body_update_ms": _stats(body),
        "resample_ms": _stats(resample),
        "resamples_distinct": len(released) == len(resample),  # none a state sampled before
        "undo_ms": _stats(undo),
        **(first_paints() if not args.no_command else {}),
        "open_s": opened,
        "compile_s": {"first_view": first_paint - opened, "drag": drag_compile},
        "handles_error_max_cm": float(max(errors)),
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "machine": machine_info(),
    }
    shown = ("body_update_ms", "resample_ms", "first_paint_s", "first_paint_cold_s", "first_inbetween_s", "first_inbetween_cold_s", "compile_s", "handles_error_max_cm", "load_average")
    summary = {k: result[k] for k in shown if k in result}
    return report(result, summary, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
