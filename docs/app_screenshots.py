#!/usr/bin/env python
"""The screenshots of docs/app.md: the real app (uvicorn on 127.0.0.1) in headless Chromium (Playwright with the
system's chromium), an s3m24 session of the reduced config (300 candidates) with four simulated tests, one of
them far from the model's prediction.

    .venv/bin/python docs/app_screenshots.py docs/figures       # writes app_start.png, app_test.png, app_end.png,
                                                                 # app_report.png (refuses to overwrite: --force)
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import threading
import time
from pathlib import Path

NAMES = ("app_start.png", "app_test.png", "app_end.png", "app_report.png")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", help="folder of the PNGs")
    ap.add_argument("--force", action="store_true", help="overwrite existing screenshots")
    ap.add_argument("--config", default="config/config.ci.yaml")
    a = ap.parse_args(argv)
    out = Path(a.out)
    clash = [n for n in NAMES if (out / n).exists()]
    if clash and not a.force:
        raise SystemExit(f"{out}: {', '.join(clash)} exist; --force overwrites them")
    import uvicorn
    from playwright.sync_api import sync_playwright

    from neckstrength.app import create_app
    from neckstrength.app.serve import free_port

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    Path("results").mkdir(exist_ok=True)
    # a folder under results/ (relative: the start page shows the sessions folder, and no machine path belongs in a
    # screenshot), removed at the end
    with tempfile.TemporaryDirectory(prefix="app-screenshots-", dir="results") as tmp:
        tmp = Path(tmp).relative_to(Path.cwd()) if Path(tmp).is_absolute() else Path(tmp)
        app = create_app(Path(tmp) / "sessions", "docs", config=a.config, cache=str(Path(tmp) / "cache"), threads=2)
        port = free_port()
        server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
        threading.Thread(target=server.run, daemon=True).start()
        while not server.started:
            time.sleep(0.05)
        base = f"http://127.0.0.1:{port}"
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=chromium, headless=True, args=["--no-sandbox", "--disable-gpu"])
            page = b.new_context(viewport={"width": 1400, "height": 900}).new_page()
            page.goto(f"{base}/?token=docs")
            page.request.post(f"{base}/api/sessions", headers={"X-Neckstrength-Token": "docs"},
                              data={"name": "P00-pilot", "participant": "P00", "model": "p2m7",
                                    "n_candidates": 2000})
            page.reload()
            page.fill("input[name=participant]", "P01")
            page.fill("input[name=name]", "P01-2026-11-28")
            page.select_option("select[name=model]", "s3m24")
            for ch in ("SCM-R", "SCM-L", "semicap-R", "semicap-L", "mf-R", "mf-L"):   # surface and fine-wire EMG
                page.check(f"input[name=emg_channel][value='{ch}']")
            page.screenshot(path=out / "app_start.png", full_page=True)
            page.click("#create-btn")
            page.wait_for_url("**/s/P01-2026-11-28", timeout=300_000)
            for k, force in enumerate(("150", "95", "160", "210"), start=2):
                page.wait_for_function("document.getElementById('step').textContent.length > 0")
                page.fill("#force", force)
                if k == 2:                      # EMG of the first test, one field per channel chosen at the start
                    page.click("details.emg summary")
                    for ch, v in (("SCM-R", "0.35"), ("SCM-L", "0.3"), ("semicap-R", "0.6"), ("semicap-L", "0.55")):
                        page.fill(f"#emg-{ch}", v)
                page.click("#record")
                page.wait_for_function(f"document.getElementById('step').textContent.startsWith('Step {k} ')",
                                       timeout=120_000)
            page.screenshot(path=out / "app_test.png", full_page=True)
            page.click("#stop")
            page.wait_for_url("**/end", timeout=120_000)
            page.screenshot(path=out / "app_end.png", full_page=True)
            page.goto(f"{base}/s/P01-2026-11-28/report")
            page.screenshot(path=out / "app_report.png", full_page=True)
            b.close()
        server.should_exit = True
        app.state.registry.close_all()
    print(f"wrote {', '.join(str(out / n) for n in NAMES)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
