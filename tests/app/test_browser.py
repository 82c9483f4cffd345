"""End to end: the real app (uvicorn in a thread) driven in headless Chromium (Playwright, Debian's chromium) through
a whole session as a clinician clicks it: start, five tests (one as best-of-3 trials), a rejected entry, undo,
reload mid-session, stop, export; the numbers equal a ``session replay`` of the same entries, and no request leaves
127.0.0.1 (usable offline)."""

from __future__ import annotations

from app_constants import CFG, P2M7, TOKEN

from neckstrength.session import SessionOptions, replay_into
from neckstrength.session.log import release


def _data_lines(path):
    return [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]


def _record(page, force, step_after):
    page.fill("#force", str(force))
    page.click("#record")
    page.wait_for_function(f"document.getElementById('step').textContent.startsWith('Step {step_after} ')")


def test_whole_session_in_the_browser(live_app, page_at, tmp_path, cache_dir):
    base, root = live_app
    page = page_at(1400, 1000)
    requests, errors = [], []
    page.on("request", lambda r: requests.append(r.url))
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{base}/?token={TOKEN}")
    page.fill("input[name=participant]", "P01")
    page.fill("input[name=name]", "P01")
    page.select_option("select[name=model]", "s3m24")         # the EMG channels offered follow the model
    page.wait_for_selector("input[name=emg_channel][value='mf-L']")
    page.select_option("select[name=model]", "p2m7")
    page.wait_for_selector("input[name=emg_channel][value='TS-E']")
    assert page.locator("input[name=emg_channel][value='mf-L']").count() == 0
    page.check("input[name=emg_channel][value='TS-B']")         # one surface EMG channel recorded
    page.click("details.more summary")
    page.fill("input[name=n_candidates]", str(P2M7["n_candidates"]))
    page.fill("input[name=seed]", str(P2M7["seed"]))
    page.click("#create-btn")
    page.wait_for_url("**/s/P01", timeout=120_000)
    page.wait_for_function("document.getElementById('step').textContent.startsWith('Step 1 ')")
    assert page.inner_text("#proposed").startswith("Test: ")
    assert page.locator("#head svg").count() == 3 and page.locator("#alternatives .bar.proposed").count() == 1
    # a rejected entry names the problem and changes nothing
    page.fill("#force", "abc")
    page.click("#record")
    assert "not a number" in page.inner_text("#force-error")
    page.fill("#force", "2500")
    page.click("#record")
    page.wait_for_function("document.getElementById('force-error').textContent.indexOf('force_N') >= 0")
    assert "implausibly large" in page.inner_text("#force-error")
    assert page.inner_text("#step").startswith("Step 1 ")
    # the test page asks for the chosen EMG channel only, as a number; a bad value is named and changes nothing
    assert page.locator("#emg-fields input.emg-in").count() == 1 and page.locator("#emg-TS-B").count() == 1
    page.click("details.emg summary")
    page.fill("#emg-TS-B", "1.5")
    page.fill("#force", "150")
    page.click("#record")
    assert "EMG TS-B" in page.inner_text("#force-error") and "outside 0-1" in page.inner_text("#force-error")
    assert page.inner_text("#step").startswith("Step 1 ")
    page.fill("#emg-TS-B", "0.4")
    # five tests: four forces and one best-of-3 (Appendix A: a third trial when the second is > 10 % above the first)
    _record(page, 150, 2)
    assert "with activations TS-B 0.4" in page.inner_text("#message") and page.input_value("#emg-TS-B") == ""
    _record(page, 120, 3)
    page.check("#best-of")
    page.fill("#force", "100")
    page.click("#record")
    assert "trial 1: 100 N" in page.inner_text("#trials") and "Rest" in page.inner_text("#trials")
    page.fill("#force", "120")
    page.click("#record")
    assert "trial 3" in page.inner_text("#trials").lower()
    page.fill("#force", "115")
    page.click("#record")
    page.wait_for_function("document.getElementById('step').textContent.startsWith('Step 4 ')")
    assert "120 N" in page.inner_text("#message")
    page.uncheck("#best-of")
    _record(page, 95, 5)
    _record(page, 210, 6)
    assert page.locator("#readings tbody tr").count() == 5 and page.locator("#radar svg").count() == 1
    # undo, then reload mid-session: the same state
    page.click("#undo")
    page.wait_for_function("document.getElementById('step').textContent.startsWith('Step 5 ')")
    shown = page.inner_text("#groups")
    page.reload()
    page.wait_for_function("document.getElementById('step').textContent.startsWith('Step 5 ')")
    assert page.inner_text("#groups") == shown
    _record(page, 180, 6)
    page.click("#stop")
    page.wait_for_url("**/s/P01/end", timeout=60_000)
    assert page.locator("img.summary-fig").count() == 1
    assert "TS-B 0.4" in page.inner_text("table.readings")          # the EMG entered, on the end page
    links = page.locator("#exports a")
    assert {links.nth(i).inner_text() for i in range(links.count())} >= {"summary.csv", "measurements.csv",
                                                                           "steps.csv", "report.html"}
    got = page.request.get(f"{base}/api/sessions/P01/files/summary.csv")
    assert got.ok and got.body() == (root / "P01" / "summary.csv").read_bytes()
    with page.expect_popup() as pop:
        page.click("#report-link")
    rep = pop.value
    rep.wait_for_load_state()
    assert "Neck muscle strength" in rep.inner_text("h1")
    # the same entries through `session replay`: identical numbers
    out = tmp_path / "replay"
    opts = SessionOptions(participant="P01", config=CFG, cache=cache_dir, emg_channels=["TS-B"],
                          **{k: v for k, v in P2M7.items() if k != "participant"})
    assert replay_into(out, opts, root / "P01" / "measurements.csv", threads=1) == 0
    assert _data_lines(out / "summary.csv") == _data_lines(root / "P01" / "summary.csv")
    assert "TS-B:0.4" in (root / "P01" / "measurements.csv").read_text()
    release(out)
    assert not errors, errors
    assert all(u.startswith(base) or u.startswith("data:") for u in requests), [u for u in requests
                                                                               if not u.startswith(base)]
