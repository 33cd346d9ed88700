"""Who may reach the editor: a random token in the printed address, as Jupyter does.

The address ``http://HOST:PORT/?token=T`` opens the page; that answer sets a cookie holding
the token (HTTP-only, same-site strict), which the page's later requests and its websocket
carry, since viser's client drops the query from the websocket address. A request with
neither the token in its query nor the cookie gets 403, and so does a websocket opened
from a page of another origin (a site the user visits cannot drive the editor).

viser has no hook for this, so :func:`gated_viser` wraps the ``websockets`` server that
viser starts while a :class:`~viser.ViserServer` is made, and raises if viser did not start
one through it: the editor never serves without the check.
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import http
import secrets
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, urlsplit

TOKEN_BYTES = 24
"""Random bytes in a token (32 URL-safe characters)."""

REFUSAL = "bezmotion edit: open the address the command printed; it carries the session's ?token=…\n"
"""The body of a refused request."""


@dataclass(frozen=True)
class TokenGate:
    """Lets through requests that carry ``token`` (in the query or the cookie), refuses the rest.

    Attributes:
      token: the secret (make one with :meth:`new`).
    """

    token: str

    @classmethod
    def new(cls) -> TokenGate:
        """A gate with a fresh random token."""
        return cls(secrets.token_urlsafe(TOKEN_BYTES))

    @property
    def cookie(self) -> str:
        """The cookie's name: one per token, so editors on one host keep their own."""
        return "bezmotion_edit_" + hashlib.sha256(self.token.encode()).hexdigest()[:12]

    def query_has_token(self, path: str) -> bool:
        """Whether the request path's query is ``?token=<token>``."""
        given = parse_qs(urlsplit(path).query).get("token", [])
        return any(self._matches(value) for value in given)

    def cookie_has_token(self, cookie_header: str | None) -> bool:
        """Whether a ``Cookie:`` header holds this gate's cookie with the token."""
        for part in (cookie_header or "").split(";"):
            name, _, value = part.strip().partition("=")
            if name == self.cookie and self._matches(value):
                return True
        return False

    def allows(self, path: str, headers: Any) -> bool:
        """Whether a request to ``path`` with ``headers`` (a mapping with ``get``) may pass.

        A websocket opened by a page of another origin is refused even with the cookie."""
        if headers.get("Upgrade", "").lower() == "websocket" and not same_origin(headers):
            return False
        return self.query_has_token(path) or self.cookie_has_token(headers.get("Cookie"))

    def set_cookie(self) -> str:
        """The ``Set-Cookie`` value that hands the token to the page's later requests."""
        return f"{self.cookie}={self.token}; Path=/; HttpOnly; SameSite=Strict"

    def wrap(self, inner: Callable | None) -> Callable:
        """A ``websockets`` ``process_request`` that checks the token, then calls ``inner``
        (viser's file server; ``None`` lets the handshake go on) and, when the query carried
        the token, adds the cookie to its answer."""

        def process_request(connection: Any, request: Any) -> Any:
            if not self.allows(request.path, request.headers):
                return connection.respond(http.HTTPStatus.FORBIDDEN, REFUSAL)
            response = inner(connection, request) if inner is not None else None
            if response is not None and self.query_has_token(request.path):
                response.headers["Set-Cookie"] = self.set_cookie()
            return response

        return process_request

    def _matches(self, value: str) -> bool:
        return hmac.compare_digest(value.encode(), self.token.encode())


def same_origin(headers: Any) -> bool:
    """Whether a request's ``Origin`` (absent: not a browser page's) names its ``Host``."""
    origin = headers.get("Origin")
    if origin is None:
        return True
    return urlsplit(origin).netloc.lower() == (headers.get("Host") or "").lower()


@contextlib.contextmanager
def gated_viser(gate: TokenGate) -> Iterator[None]:
    """Within it, every ``websockets`` server started (viser's, as a ``ViserServer`` is made)
    checks ``gate``; on leaving, raise if none was started through it.

    Raises:
      RuntimeError: viser started its server some other way (a viser version this code does
        not know): the editor would have served without the token check.
    """
    import websockets.asyncio.server as ws_server

    original = ws_server.serve
    started = []

    def serve(handler, *args, process_request=None, **kwargs):
        started.append(True)
        return original(handler, *args, process_request=gate.wrap(process_request), **kwargs)

    ws_server.serve = serve
    try:
        yield
    finally:
        ws_server.serve = original
    if not started:
        raise RuntimeError("viser started its server without the editor's token check (an unknown viser version); not serving")


__all__ = ["REFUSAL", "TOKEN_BYTES", "TokenGate", "gated_viser", "same_origin"]
