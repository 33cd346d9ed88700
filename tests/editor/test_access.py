"""Nothing reaches the editor without its token: the page, its files and its websocket.

The gate's rules on plain requests first, then a served editor asked over HTTP and
websocket with and without the token (no browser: ``test_browser.py`` opens the page).
"""

from __future__ import annotations

import urllib.error
import urllib.request

import pytest

from bezmotion.editor.access import REFUSAL, TokenGate, same_origin

TOKEN = "s3cret-token_0123456789abcdefghij"


@pytest.fixture
def gate() -> TokenGate:
    return TokenGate(TOKEN)


def test_a_request_passes_with_the_token_in_its_query_or_cookie_only(gate):
    assert gate.allows(f"/?token={TOKEN}", {})
    assert gate.allows("/assets/index.js", {"Cookie": f"other=1; {gate.cookie}={TOKEN}"})
    for path, headers in [
        ("/", {}),
        ("/?token=", {}),
        (f"/?token={TOKEN[:-1]}", {}),
        (f"/?tokens={TOKEN}", {}),
        ("/", {"Cookie": f"{gate.cookie}={TOKEN}x"}),
        ("/", {"Cookie": f"bezmotion_edit_other={TOKEN}"}),  # another editor's cookie name
    ]:
        assert not gate.allows(path, headers), (path, headers)


def test_a_websocket_from_another_origin_is_refused_even_with_the_cookie(gate):
    cookie = {"Cookie": f"{gate.cookie}={TOKEN}", "Upgrade": "websocket", "Host": "127.0.0.1:8080"}
    assert gate.allows("/", {**cookie, "Origin": "http://127.0.0.1:8080"})
    assert gate.allows("/", cookie)  # no Origin: not a browser page
    assert not gate.allows("/", {**cookie, "Origin": "http://evil.example"})
    assert not gate.allows("/", {**cookie, "Origin": "http://127.0.0.1:9999"})
    assert same_origin({"Origin": "http://LOCALHOST:8080", "Host": "localhost:8080"})


def test_fresh_gates_have_distinct_tokens_and_cookies():
    a, b = TokenGate.new(), TokenGate.new()
    assert a.token != b.token and a.cookie != b.cookie and len(a.token) >= 32
    assert a.token not in a.cookie  # the name does not give the token away


# --------------------------------------------------------------------- a served editor

viser = pytest.importorskip("viser", reason="the browser editor needs viser: pip install -e '.[editor]'")
from websockets.exceptions import InvalidStatus  # noqa: E402 (viser's dependency)
from websockets.sync.client import connect  # noqa: E402

from bezmotion.editor.app import serve  # noqa: E402


@pytest.fixture
def app(session):
    app = serve(session, port=0, token=TOKEN)
    yield app
    app.stop()


def get(url: str, headers: dict | None = None):
    """``(status, headers, body)`` of a GET."""
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers or {}), timeout=30) as answer:
            return answer.status, answer.headers, answer.read()
    except urllib.error.HTTPError as error:
        return error.code, error.headers, error.read()


def test_the_page_and_its_files_answer_403_without_the_token(app):
    status, _, body = get(app.base_url + "/")
    assert (status, body.decode()) == (403, REFUSAL)
    assert get(app.base_url + "/index.html")[0] == 403
    assert get(app.base_url + "/?token=wrong")[0] == 403


def test_the_tokened_address_sets_the_cookie_later_requests_carry(app):
    assert app.url == f"{app.base_url}/?token={TOKEN}"
    status, headers, body = get(app.url)
    assert status == 200 and b"<html" in body.lower()
    cookie = headers["Set-Cookie"]
    assert cookie.startswith(f"{app.gate.cookie}={TOKEN};") and "HttpOnly" in cookie and "SameSite=Strict" in cookie
    assert get(app.base_url + "/", {"Cookie": cookie.split(";")[0]})[0] == 200


def test_the_websocket_needs_the_cookie_and_the_pages_origin(app):
    ws_url = app.base_url.replace("http://", "ws://")
    with pytest.raises(InvalidStatus) as refused:
        connect(ws_url, open_timeout=30).close()
    assert refused.value.response.status_code == 403
    cookie = {"Cookie": f"{app.gate.cookie}={TOKEN}"}
    with pytest.raises(InvalidStatus):
        connect(ws_url, additional_headers={**cookie, "Origin": "http://evil.example"}, open_timeout=30).close()
    connect(ws_url, additional_headers={**cookie, "Origin": app.base_url}, open_timeout=30).close()  # the page's own
