"""The viser app without a browser: serving in the background, sharing off."""

from __future__ import annotations

import pytest

pytest.importorskip("viser", reason="the browser editor needs viser: pip install -e '.[editor]'")

from bezmotion.editor.app import serve  # noqa: E402


def test_served_in_the_background_the_page_has_the_clip_before_the_inbetween(session):
    app = serve(session, port=0, background=True)
    try:
        assert app.ready.wait(timeout=300), "the first view was never drawn"
        app.settle()
        with app.lock:  # the thread compiles the drag after the first view, under the lock
            assert session.state.handles == () and app.message == ""
        assert app.status.content == "every handle met"
    finally:
        app.stop()


def test_the_share_button_is_off_and_a_share_request_opens_no_tunnel(session):
    app = serve(session, port=0)
    try:
        assert app.server.request_share_url() is None
        assert "sharing is off" in app.message
    finally:
        app.stop()


def test_the_panels_keys_seed_ik_and_files_edit_the_session(session):
    app = serve(session, port=0)
    try:
        app._edit(lambda: app._add_handle_on("left_hand"))
        assert [(h.joint, h.frame) for h in session.state.handles] == [("left_hand", int(app.frame.value))]
        first_seed = session.state.seed
        app._edit(session.resample)
        assert app.seed.value == str(session.state.seed) != str(first_seed) and str(first_seed) in app.seed.options
        app.seed.value = str(first_seed)
        app._edit(app._use_seed)
        assert session.state.seed == first_seed and app.message == f"seed {first_seed}"
        app.export_name.value = "take"
        app._edit(app._export)
        app._edit(lambda: session.delete_handle(session.state.handles[0].id))
        app._edit(app._open_handles)
        assert app.message == "opened take.handles.json" and len(session.state.handles) == 1
        app.keys.value = "0 30 99"
        app._edit(app._set_keys)
        assert app.message.startswith("error:")  # the clip has 40 frames: the keys stay
        assert session.state.keys == (0, 30)
        app.keys.value = "0 20 39"
        app._edit(app._set_keys)
        assert session.state.keys == (0, 20, 39) and app.message == "keys at clip frames 0 20 39"
        app._edit(session.undo)
        assert app.keys.value == "0 30"  # the panel follows the state
        app.keys.value = "0 x"
        app._edit(app._set_keys)
        assert "whole numbers" in app.message
        app._edit(lambda: None)  # a control with nothing to do keeps the last message
        assert "whole numbers" in app.message
        app.export_name.value = "nowhere"
        app._edit(app._open_handles)
        assert app.message.startswith("error:") and len(session.state.handles) == 1
    finally:
        app.stop()
