"""The app's fixtures: an app on a temporary sessions folder with CI-sized settings (p2m7, 2,000 candidates, the
reduced config), a TestClient speaking to it as 127.0.0.1, and the real app served by uvicorn in a thread for the
browser tests (headless Chromium: the shared ``browser`` / ``page_at`` of tests/conftest.py)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from app_constants import CFG, HDR, P2M7, ROOT, TOKEN  # noqa: F401  (shared with the test modules)


@pytest.fixture(scope="session")
def cache_dir(tmp_path_factory):
    """One candidate-set cache for every app test (the p2m7 set is built once)."""
    return str(tmp_path_factory.mktemp("session_cache"))


@pytest.fixture
def make_app(tmp_path, cache_dir):
    """``make_app(**kw)`` -> (app, sessions folder); closed (folders released) after the test."""
    from neckstrength.app import create_app

    apps = []

    def make(**kw):
        root = tmp_path / "sessions"
        app = create_app(root, TOKEN, config=CFG, cache=cache_dir, threads=1, **kw)
        apps.append(app)
        return app, root

    yield make
    for a in apps:
        a.state.registry.close_all()


@pytest.fixture
def client(make_app):
    from fastapi.testclient import TestClient

    app, root = make_app()
    c = TestClient(app, base_url="http://127.0.0.1", headers=HDR)
    c.root = root
    return c


@pytest.fixture
def live_app(make_app):
    """The real app served by uvicorn on 127.0.0.1 (a free port) in a thread: (base URL, sessions folder)."""
    import uvicorn

    from neckstrength.app.serve import free_port

    app, root = make_app()
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    t0 = time.time()
    while not server.started:
        if time.time() - t0 > 30:
            raise RuntimeError("uvicorn did not start in 30 s")
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}", root
    server.should_exit = True
    th.join(10)
