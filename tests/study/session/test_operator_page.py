"""The operator page in headless Chromium under its CSP: status, buttons enabled only when valid, runner stopped."""

from playwright.sync_api import expect, sync_playwright

from study.session.uistate import UiState
from study.session.webui import WebUI

from tests.support.needs import chromium

CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]
BUTTONS = ("confirm", "pause", "resume", "endfam", "abort")


def enabled(page) -> dict:
    return {b: page.locator(f"#{b}").is_enabled() for b in BUTTONS}


def test_operator_page_status_buttons_and_runner_stopped():
    ui = UiState()
    web = WebUI(ui, token="tok-1").start()
    try:
        ui.set_operator(subject="P07", phase="familiarization", trial=2, trials_total=24, trials_valid=0,
                        trial_n=None, time_left_s=None, last_rating=None, audio="espeak-ng", link="ok")
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=chromium(), args=CHROMIUM_ARGS)
            page = b.new_page()  # CSP enforced: scripts are files
            page.goto(web.operator_url)
            expect(page.locator("#subject")).to_have_text("P07", timeout=5000)
            expect(page.locator("#runner")).to_contain_text("runner running")
            assert enabled(page) == {"confirm": False, "pause": True, "resume": False, "endfam": True, "abort": True}
            ui.request_confirm("placeholder A")
            ui.set_operator(phase="testing", trial_n=5, trials_valid=4, time_left_s=125.0, last_rating="6")
            expect(page.locator("#trialn")).to_have_text("5 of 24 (4 valid)", timeout=5000)
            expect(page.locator("#timeleft")).to_have_text("2 min 5 s")
            expect(page.locator("#lastrating")).to_have_text("6")
            expect(page.locator("#audiolink")).to_have_text("espeak-ng / ok")
            assert enabled(page) == {"confirm": True, "pause": True, "resume": False, "endfam": False, "abort": True}
            page.click("#pause")
            expect(page.locator("#resume")).to_be_enabled(timeout=5000)
            assert enabled(page) == {"confirm": False, "pause": False, "resume": True, "endfam": False, "abort": True}
            assert ui.snapshot("operator")["paused"]
            # the runner goes away: the page says so and disables every button
            web.stop()
            expect(page.locator("#runner")).to_contain_text("RUNNER STOPPED", timeout=5000)
            assert not any(enabled(page).values())
            b.close()
    finally:
        try:
            web.stop()
        except Exception:
            pass
