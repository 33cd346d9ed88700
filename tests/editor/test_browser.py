"""The browser editor in a real browser: Debian's chromium, headless, driven by playwright.

The page answers 403 without the token and loads and draws the 3-D view with it; a handle is
added with the panel's button and its gizmo dragged with the mouse (its arrow found by
projecting it through the page's camera), another by clicking a joint's ball; a second tab sees the same session and exports a
BVH that reads back; closing the first tab loses nothing. Skipped without viser, playwright
or /usr/bin/chromium.
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

from bezmotion.editor.app import SCALE, serve  # noqa: E402 (after the skips: it needs viser only when serving)

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


def screen_point(page, client, point_m: np.ndarray) -> tuple[float, float]:
    """Where the page draws ``point_m`` ``(3,)`` m: a pinhole projection through the client's
    camera (its vertical field of view; Y up) into the canvas."""
    box = page.locator("canvas").first.bounding_box()
    camera = client.camera
    eye = np.asarray(camera.position)
    forward = np.asarray(camera.look_at) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(camera.up_direction))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    offset = point_m - eye
    depth, half = offset @ forward, np.tan(camera.fov / 2)
    x = (offset @ right) / (depth * half * box["width"] / box["height"])
    y = (offset @ up) / (depth * half)
    return box["x"] + box["width"] * (1 + x) / 2, box["y"] + box["height"] * (1 - y) / 2


def drag_up(page, start: tuple[float, float], pixels: int, steps: int = 10) -> None:
    """Press the mouse at ``start`` and move it ``pixels`` up in ``steps``, then let go."""
    page.mouse.move(*start)
    page.mouse.down()
    for step in range(1, steps + 1):
        page.mouse.move(start[0], start[1] - pixels * step / steps)
        page.wait_for_timeout(50)
    page.mouse.up()


def launch(playwright):
    return playwright.chromium.launch(
        executable_path=str(CHROMIUM), args=["--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
    )


def open_editor(browser, app, clients: int):
    """A new tab (its own cookies) on the editor's address, once it is the ``clients``-th connected."""
    page = browser.new_context(viewport={"width": 1280, "height": 800}).new_page()
    page.goto(app.url)
    page.wait_for_selector("canvas", timeout=WAIT_S * 1000)
    until(lambda: len(app.server.get_clients()) >= clients, f"tab {clients} to connect")
    page.wait_for_timeout(3000)  # the scene's messages drawn
    return page


def test_the_editor_in_a_browser_adds_drags_and_exports(clip, exact_model, tmp_path):
    session = EditSession(clip, {"exact": exact_model}, tmp_path / "out", options=options())
    session.warm_up()
    app = serve(session, port=0)
    try:
        with sync_api.sync_playwright() as playwright:
            browser = launch(playwright)
            stranger = browser.new_page()
            assert stranger.goto(app.base_url).status == 403, "the editor answered without its token"
            stranger.close()

            page = open_editor(browser, app, clients=1)
            assert pixel_spread(page.locator("canvas").first.screenshot()) > 0.02, "the 3-D view is blank"
            app.frame.value = 12
            page.get_by_role("button", name="Add handle").click()
            until(lambda: len(session.state.handles) == 1, "the Add handle button's handle")
            page.wait_for_timeout(1500)  # the gizmo drawn
            with app.lock:
                hand = session.state.handles[0]
                before = session.view.joints.copy()
            assert (hand.joint, hand.frame) == ("right_hand", 12)
            start = np.asarray(hand.position)

            client = app.server.get_clients()[min(app.server.get_clients())]
            arrow = screen_point(page, client, (start + np.array([0.0, 14.0, 0.0])) * SCALE)  # up the gizmo's Y arrow (20 cm)
            drag_up(page, arrow, pixels=60)
            until(lambda: session.state.handles[0].position[1] > start[1] + 5.0, "the mouse drag to move the handle up")
            app.settle()
            with app.lock:
                view, moved = session.view, np.asarray(session.state.handles[0].position)
            assert np.abs(moved - start)[[0, 2]].max() < 0.5, "the Y arrow moved the handle off its axis"
            assert np.abs(view.joints - before).max() > 1.0, "the served motion did not change"
            assert view.handle_errors[hand.id] < MET_CM and view.misses == ()
            page.wait_for_timeout(1000)
            shot = page.screenshot()
            if os.environ.get("BEZMOTION_EDITOR_SCREENSHOT"):
                Path(os.environ["BEZMOTION_EDITOR_SCREENSHOT"]).write_bytes(shot)

            app.frame.value = 20  # a click on the left hand's ball there adds a handle on it
            page.wait_for_timeout(1500)
            with app.lock:
                ball = session.view.positions[20, CHARACTERISTIC_JOINTS.index("left_hand")] * SCALE
            page.mouse.click(*screen_point(page, client, ball))
            until(lambda: len(session.state.handles) == 2, "the click on the left hand's ball to add a handle")
            assert (session.state.handles[1].joint, session.state.handles[1].frame) == ("left_hand", 20)

            second = open_editor(browser, app, clients=2)  # a second tab: the same session
            second.get_by_text(f"handle {hand.id}:", exact=False).wait_for(timeout=10_000)
            boxes = second.get_by_role("textbox")  # viser's labels are not tied to their inputs: the Name box is the one saying "edit"
            name = next(boxes.nth(i) for i in range(boxes.count()) if boxes.nth(i).input_value() == "edit")
            name.fill("take")
            until(lambda: app.export_name.value == "take", "the Name box's text to reach the server", 10)
            second.get_by_role("button", name="Export").click()
            bvh = tmp_path / "out" / "take.bvh"
            until(bvh.exists, "the Export button's BVH")
            page.context.close()  # the first tab closed: what was exported stays, the session goes on
            until(lambda: len(app.server.get_clients()) == 1, "the first tab to disconnect", 10)
            second.get_by_role("button", name="Undo").click()
            until(lambda: len(session.state.handles) == 1, "the second tab's undo of the click's handle")
            browser.close()
    finally:
        app.stop()
    motion = bm.read_bvh(bvh)
    assert motion.num_frames >= session.frames
