"""Helpers of the editor's tests (``from editor.common import …``)."""

from __future__ import annotations

import bezmotion as bm

STEPS = 2  # DDIM steps: the session's plumbing, not the motion's quality


def options(**changes) -> bm.InbetweenOptions:
    """The sessions' options: few steps, feet locked (the command's default)."""
    return bm.InbetweenOptions(steps=STEPS, foot_lock=True, **changes)


def counting(ik_fn):
    """``ik_fn`` recording each trace in ``.traces`` (Python runs only while JAX traces), so
    a test can tell whether an edit compiled anything."""

    def ik(params, targets):
        ik.traces.append(1)
        return ik_fn(params, targets)

    ik.traces = []
    return ik
