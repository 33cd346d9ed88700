"""The browser editor in a real browser: Debian's chromium, headless, driven by playwright.

The page loads and draws the 3-D view; a handle is added with the panel's button, its gizmo
dragged (the events a gizmo sends, queued as the browser's are), and the export button
writes a BVH that reads back. Skipped without viser, playwright or /usr/bin/chromium.
``BEZMOTION_EDITOR_SCREENSHOT=PATH`` keeps the page's screenshot there (the docs' picture).
"""

from __future__ import annotations

import io
import os
import time
from pathlib import Path

import numpy as np
import pytest
from editor.common import options

import bezmotion as bm
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.editor import EditSession

CHROMIUM = Path("/usr/bin/chromium")
pytest.importorskip("viser", reason="the browser editor needs viser: pip install -e '.[editor]'")
sync_api = pytest.importorskip("playwright.sync_api", reason="the browser test needs playwright (the test extra)")
pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason=f"the browser test drives the system chromium, not found at {CHROMIUM}")

from bezmotion.editor.app import serve  # noqa: E402 (after the skips: it needs viser only when serving)

HAND = CHARACTERISTIC_JOINTS.index("right_hand")
MET_CM = 0.05  # the editor's promise: every handle met this closely after every edit and drag
WAIT_S = 120.0  # the first paint and the first handle compile on a busy 2-core CPU


def until(predicate, what: str, timeout: float = WAIT_S) -> None:
    """Wait until ``predicate()`` holds (``timeout`` s), else fail saying ``what``."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.1)


def pixel_spread(png: bytes) -> float:
    """The standard deviation of a PNG's RGB values (0–1): near 0 for a blank image."""
    import matplotlib.image

    return float(matplotlib.image.imread(io.BytesIO(png), format="png")[..., :3].std())


@pytest.fixture(scope="module")
def exact_model():
    return bm.pretrained("bandai_namco", ik="exact")  # the editor's drags warm-start the exact IK


def test_the_editor_in_a_browser_adds_drags_and_exports(clip, exact_model, tmp_path):
    session = EditSession(clip, {"exact": exact_model}, tmp_path / "out", options=options())
    session.warm_up()
    app = serve(session, port=0)
    try:
        with sync_api.sync_playwright() as playwright:
            browser = playwright.chromium.launch(
                executable_path=str(CHROMIUM), args=["--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
            )
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(app.url)
            page.wait_for_selector("canvas", timeout=WAIT_S * 1000)
            until(lambda: len(app.server.get_clients()) > 0, "the page to connect")
            page.wait_for_timeout(3000)  # the scene's messages drawn
            assert pixel_spread(page.locator("canvas").first.screenshot()) > 0.02, "the 3-D view is blank"

            app.frame.value = 12
            page.get_by_role("button", name="Add handle").click()
            until(lambda: len(session.state.handles) == 1, "the Add handle button's handle")
            with app.lock:
                hand = session.state.handles[0]
                before = session.view.joints.copy()
            assert (hand.joint, hand.frame) == ("right_hand", 12)
            start = np.asarray(hand.position)
            app.move(hand.id, start, "start")
            for step in range(1, 6):  # a gizmo dragged up and forward
                app.move(hand.id, start + step * np.array([0.0, 4.0, 2.0]), "update")
            target = start + np.array([0.0, 20.0, 10.0])
            app.move(hand.id, target, "end")
            app.settle()
            with app.lock:
                view = session.view
                assert session.state.handles[0].position == pytest.approx(tuple(target))
            assert np.abs(view.joints - before).max() > 1.0, "the served motion did not change"
            assert view.handle_errors[hand.id] < MET_CM and view.misses == ()
            page.wait_for_timeout(1000)
            shot = page.screenshot()
            if os.environ.get("BEZMOTION_EDITOR_SCREENSHOT"):
                Path(os.environ["BEZMOTION_EDITOR_SCREENSHOT"]).write_bytes(shot)

            boxes = page.get_by_role("textbox")  # viser's labels are not tied to their inputs: the Name box is the one saying "edit"
            name = next(boxes.nth(i) for i in range(boxes.count()) if boxes.nth(i).input_value() == "edit")
            name.fill("take")
            until(lambda: app.export_name.value == "take", "the Name box's text to reach the server", 10)
            page.get_by_role("button", name="Export").click()
            bvh = tmp_path / "out" / "take.bvh"
            until(bvh.exists, "the Export button's BVH")
            browser.close()
    finally:
        app.stop()
    motion = bm.read_bvh(bvh)
    assert motion.num_frames >= session.frames and app.message.startswith("exported")
