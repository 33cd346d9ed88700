"""Benchmark: how live the editor feels, a recorded editing session driven through its API.

The bundled clip and models (``EditSession.open``, the IK ``auto`` picks: the exact IK on
the learned IK's poses), one 31-frame window, a right-hand handle at frame 12 and a left-foot
pin at frame 20. The recording drags the hand through ``--waypoints`` (cm from where its
curve was), ``--moves`` gizmo moves per drag eased in and out, and releases after each drag.

- ``body_update_ms``: one :meth:`EditSession.drag`, the curves re-projected onto the handle
  (no diffusion) and the body solved by the exact IK from the previous move's (median, p95).
- ``resample_ms``: one :meth:`EditSession.release`, a full resample through the handles.
- ``undo_ms``: one :meth:`EditSession.undo` back over a release (its view kept).
- ``first_paint_s``: from opening the session (reading the clip, loading the models) to its
  first view, compiling included; ``compile_s`` has the compilations apart: the in-between
  (the first view: compiling and one sample) and the drag (:meth:`EditSession.warm_up`).
  No persistent compilation cache is used: a first start on a fresh machine.
- ``handles_error_max_cm``: the farthest any handle lay from its joint after any move or release.

Timings are steady state (everything compiled first), with the machine and its load average
before and after (another process on the cores slows every figure).

    python benchmarks/editor_latency.py --out editor_latency.json
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

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
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")


def _stats(values_s: list[float]) -> dict[str, float]:
    ms = 1e3 * np.asarray(values_s)
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "max": float(ms.max()), "count": len(ms)}


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
        "first_paint_s": first_paint,
        "open_s": opened,
        "compile_s": {"first_view": first_paint - opened, "drag": drag_compile},
        "handles_error_max_cm": float(max(errors)),
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "machine": machine_info(),
    }
    summary = {k: result[k] for k in ("body_update_ms", "resample_ms", "first_paint_s", "compile_s", "handles_error_max_cm", "load_average")}
    return report(result, summary, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
