"""Serving the app: 127.0.0.1 on a free port by default, the URL with its access token printed, the browser opened."""

from __future__ import annotations

import secrets
import socket
import sys
import threading
import webbrowser
from typing import Callable

from neckstrength.app.security import LOCAL_HOSTS


def new_token() -> str:
    """A fresh random access token (48 hex characters, as Jupyter's)."""
    return secrets.token_hex(24)


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def serve(root: str = "sessions", config: str = "config/config.yaml", host: str = "127.0.0.1", port: int = 0,
          token: str | None = None, open_browser: bool = True, threads: int | None = None, cache: str | None = None,
          say: Callable[[str], None] = print) -> int:
    """Run the app until interrupted (Ctrl-C). ``port`` 0: a free port. Returns 0."""
    import uvicorn

    from neckstrength.app.server import create_app

    token = token or new_token()
    port = port or free_port(host)
    hosts = LOCAL_HOSTS if host in LOCAL_HOSTS else (*LOCAL_HOSTS, host)
    app = create_app(root, token, config=config, cache=cache, threads=threads, hosts=hosts)
    shown = f"[{host}]" if ":" in host else host
    url = f"http://{shown}:{port}/?token={token}"
    say(f"neckstrength app: sessions in {root}/ ; open {url}")
    say("  (the token is needed on every request; Ctrl-C stops the app; every acknowledged entry is on disk)")
    if host not in LOCAL_HOSTS:
        say(f"  WARNING: bound to {host}, not only this machine: anyone who can reach it and has the token can drive "
            "a session")
    if open_browser:
        threading.Timer(1.0, lambda: webbrowser.open(url)).start()
    sys.stdout.flush()
    uvicorn.run(app, host=host, port=port, log_level="warning")
    return 0
