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
