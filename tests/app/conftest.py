"""The app's fixtures: an app on a temporary sessions folder with CI-sized settings (p2m7, 2,000 candidates, the
reduced config), a TestClient speaking to it as 127.0.0.1, and the real app served by uvicorn in a thread for the
browser tests (headless Chromium: the shared launch of tests/browser/conftest.py)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CFG = str(ROOT / "config" / "config.ci.yaml")
TOKEN = "test-token-0123456789"
HDR = {"X-Neckstrength-Token": TOKEN}
P2M7 = {"model": "p2m7", "participant": "P01", "n_candidates": 2000, "seed": 7}


SHARED_BROWSER = ROOT / "tests" / "browser" / "conftest.py"


def _shared_browser_fixtures():
    """tests/browser/conftest.py (the shared headless Chromium: ``browser``, ``page_at``) loaded under its own name."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_neckstrength_browser_fixtures", SHARED_BROWSER)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


if SHARED_BROWSER.is_file():
    _b = _shared_browser_fixtures()
    browser, page_at, chromium_path = _b.browser, _b.page_at, _b.chromium_path
else:                                   # the same launch, until the shared set-up is in the tree
    import os
    import shutil

    def chromium_path() -> str:
        """Debian's chromium (``$CHROMIUM`` first); never Playwright's own browser download."""
        for name in (os.environ.get("CHROMIUM"), "chromium", "chromium-browser"):
            if name and shutil.which(name):
                return shutil.which(name)
        raise RuntimeError("no Chromium found: install Debian's `chromium` (apt-get install chromium) or set CHROMIUM")

    @pytest.fixture(scope="session")
    def browser():
        from playwright.sync_api import sync_playwright

        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=chromium_path(), headless=True,
                                  args=["--no-sandbox", "--disable-gpu"])
            try:
                yield b
            finally:
                b.close()

    @pytest.fixture
    def page_at(browser):
        contexts = []

        def make(width: int = 1400, height: int = 1000):
            ctx = browser.new_context(viewport={"width": width, "height": height})
            contexts.append(ctx)
            return ctx.new_page()

        yield make
        for ctx in contexts:
            ctx.close()


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
