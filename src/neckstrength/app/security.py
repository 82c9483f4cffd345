"""Safe as a local server: the access token, the Host check and no cross-site writes
==================================================================================

- **Token** (as Jupyter does): a random token is printed with the app's URL (``?token=...``); every request needs
  it, in the URL, in the ``X-Neckstrength-Token`` header, or in the cookie the first tokened page sets
  (``HttpOnly``, ``SameSite=Strict``).
- **Host header** must name this machine (``127.0.0.1``, ``localhost``, ``::1`` or the host the app was bound to):
  a page on another site that re-points its DNS name to 127.0.0.1 (DNS rebinding) is refused.
- **State-changing requests** (POST, PUT, PATCH, DELETE) need the token in the header or the URL, never the cookie
  alone: a form or script on another site cannot set the header (a cross-origin request with it needs a CORS
  preflight this app never grants), so no other site can drive a session.
"""

from __future__ import annotations

import hmac
import json
from http.cookies import SimpleCookie
from urllib.parse import parse_qs

COOKIE = "neckstrength_token"
HEADER = "x-neckstrength-token"
LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")


def host_name(host: str) -> str:
    """The host of a Host header without its port (``[::1]:8000`` -> ``::1``)."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1:host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


class TokenHostMiddleware:
    """ASGI middleware refusing (403, JSON naming the problem) a request with a foreign Host header or without the
    token; a GET with the right token in the URL gets the cookie."""

    def __init__(self, app, token: str, hosts=LOCAL_HOSTS):
        self.app = app
        self.token = token
        self.hosts = tuple(h.lower() for h in hosts)

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        host = host_name(headers.get("host", ""))
        if host not in self.hosts:
            return await _refuse(send, 403, "host", f"Host header '{headers.get('host', '')}' is not this machine "
                                 f"({', '.join(self.hosts)}): refused (DNS rebinding protection)")
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        url_token = (query.get("token") or [""])[0]
        header_token = headers.get(HEADER, "")
        cookie = SimpleCookie()
        try:
            cookie.load(headers.get("cookie", ""))
        except Exception:
            pass
        cookie_token = cookie[COOKIE].value if COOKIE in cookie else ""
        ok = self._match(url_token) or self._match(header_token)
        method = scope.get("method", "GET")
        if not ok and method in SAFE_METHODS and self._match(cookie_token):
            ok = True
        if not ok:
            why = ("a state-changing request needs the token in the X-Neckstrength-Token header"
                   if method not in SAFE_METHODS and self._match(cookie_token) else
                   "missing or wrong access token: open the URL the app printed at start (it ends in ?token=...)")
            return await _refuse(send, 403, "token", why)
        if self._match(url_token) and method in SAFE_METHODS:
            async def send_cookie(msg):
                if msg["type"] == "http.response.start":
                    msg = dict(msg)
                    msg["headers"] = list(msg.get("headers", [])) + [(
                        b"set-cookie", f"{COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict".encode())]
                await send(msg)

            return await self.app(scope, receive, send_cookie)
        return await self.app(scope, receive, send)

    def _match(self, given: str) -> bool:
        return bool(given) and hmac.compare_digest(given.encode(), self.token.encode())


async def _refuse(send, status: int, field: str, msg: str):
    body = json.dumps({"detail": [{"loc": [field], "msg": msg, "type": "forbidden"}]}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]})
    await send({"type": "http.response.body", "body": body})
