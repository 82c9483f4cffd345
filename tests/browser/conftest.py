"""Headless Chromium for the tests that look at a page as a user's browser shows it (the Snakemake report here;
later the browser app).

The browser is Debian's ``chromium`` (``test.sh`` installs it when missing), driven by Playwright for Python with
``executable_path``: Playwright's own browser downloads are never used. A missing browser is a failure that says
how to install it, not a skip.
"""

from __future__ import annotations

import os
import shutil

import pytest

CHROMIUM_NAMES = ("chromium", "chromium-browser")


def chromium_path() -> str:
    """Path of the system Chromium (``$CHROMIUM`` first), or a clear error."""
    for name in (os.environ.get("CHROMIUM"), *CHROMIUM_NAMES):
        if name and shutil.which(name):
            return shutil.which(name)
    raise RuntimeError("no Chromium found: install Debian's `chromium` (apt-get install chromium; test.sh does "
                       "this when missing) or set CHROMIUM to a Chromium executable")


@pytest.fixture(scope="session")
def browser():
    """One headless Chromium for the session (Playwright, system browser)."""
    from playwright.sync_api import sync_playwright

    path = chromium_path()
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=path, headless=True, args=["--no-sandbox", "--disable-gpu"])
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page_at(browser):
    """``page_at(width, height)``: a fresh page (own context) with that window size; closed after the test."""
    contexts = []

    def make(width: int = 1400, height: int = 1000):
        ctx = browser.new_context(viewport={"width": width, "height": height})
        contexts.append(ctx)
        return ctx.new_page()

    yield make
    for ctx in contexts:
        ctx.close()
