"""The console page in a real headless Chromium (Debian's chromium, driven by Playwright)
against a real daemon with simulated drives: load, home, jog, choose a program (preview
drawn), start, hold, resume, completion in the history. Screenshots (desktop and phone
width) go to ``$NURBSMOTION_SCREENSHOTS`` or the test's tmp folder, to be looked at."""

from __future__ import annotations

import asyncio
import os
import re
import shutil
import threading
import uuid
from pathlib import Path
from typing import Any, Iterator

import pytest

from nurbsmotion.config import load_config
from nurbsmotion.web.app import WebSettings, make_app
from tests.web.ports import free_port
from tests.integration.daemon_helpers import DaemonProcess

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (scripts/test installs it)"),
              pytest.mark.slow]

MACHINE = """\
cycle_period_ms: 4
simulate: true
bus: {{interface: virtual, channel: {channel}}}
interpolation: {{algorithm: lookahead, feed_mm_min: 3000, chord_error_mm: 0.01, max_accel_mm_s2: 1000,
                max_jerk_mm_s3: 50000}}
axes:
  - {{name: X, node_id: 1, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-100, 100], max_velocity_mm_s: 200,
     homing: {{method: here, offset_mm: 0}}}}
  - {{name: Y, node_id: 2, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-100, 100], max_velocity_mm_s: 200,
     homing: {{method: here, offset_mm: 0}}}}
  - {{name: Z, node_id: 3, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-100, 100], max_velocity_mm_s: 200,
     homing: {{method: here, offset_mm: 0}}}}
control: {{socket: {socket}}}
data_dir: {data_dir}
"""
PART = """(a square pocket outline with an arc corner)
G21 G90
G00 Z5
G00 X0 Y0
G01 Z-1 F300
G01 X30 F1200
G01 Y20
G03 X20 Y30 I-10 J0
G01 X0
G01 Y0
G00 Z5
M30
"""
BROWSER_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync"]



@pytest.fixture(scope="module")
def console(tmp_path_factory) -> Iterator[tuple[str, Any]]:
    """The daemon in its own process (as in production: the browser, Playwright and the
    gateway's event loop in this process must not share an interpreter lock with the
    simulated drives), its gateway on a loopback port (a thread's event loop), the URL."""
    from aiohttp import web

    daemon = DaemonProcess(tmp_path_factory.mktemp("page") / "data")
    daemon.config_path.write_text(MACHINE.format(channel=f"page-{uuid.uuid4().hex}", socket=daemon.socket,
                                                 data_dir=daemon.data_dir))
    daemon.config = load_config(daemon.config_path)
    settings = WebSettings(socket=str(daemon.socket), data_dir=str(daemon.data_dir), port=free_port())
    loop = asyncio.new_event_loop()
    runner = web.AppRunner(make_app(settings))
    started = threading.Event()

    def serve() -> None:
        asyncio.set_event_loop(loop)
        loop.run_until_complete(runner.setup())
        loop.run_until_complete(web.TCPSite(runner, settings.host, settings.port).start())
        started.set()
        loop.run_forever()

    thread = threading.Thread(target=serve, daemon=True)
    try:
        daemon.start()  # in the try: a daemon that answers too late is still ended (it kept running before)
        thread.start()
        assert started.wait(20.0)
        yield f"http://{settings.host}:{settings.port}/", daemon
    finally:
        if started.is_set():
            asyncio.run_coroutine_threadsafe(runner.cleanup(), loop).result(10.0)
        loop.call_soon_threadsafe(loop.stop)
        if thread.is_alive():
            thread.join(5.0)
        daemon.close()


def shots_dir(tmp_path: Path) -> Path:
    folder = Path(os.environ.get("NURBSMOTION_SCREENSHOTS") or tmp_path)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def canvas_is_drawn(page: Any) -> bool:
    """Some pixels of the preview differ from its background (a path was drawn)."""
    return bool(page.evaluate("""() => {
        const c = document.querySelector('[data-testid=preview]');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let lit = 0;  // pixels clearly unlike the background #0b0d10
        for (let i = 0; i < d.length; i += 4) if (Math.abs(d[i] - 11) + Math.abs(d[i + 1] - 13) + Math.abs(d[i + 2] - 16) > 90) lit++;
        return lit > 500;
    }"""))


def test_the_console_homes_jogs_previews_and_runs_a_program(console, tmp_path):
    from playwright.sync_api import expect, sync_playwright

    url, daemon = console
    program = tmp_path / "pocket.nc"
    program.write_text(PART)
    shots = shots_dir(tmp_path)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=BROWSER_ARGS)
        page = browser.new_page(viewport={"width": 1600, "height": 1000})
        errors: list[str] = []
        page.on("pageerror", lambda err: errors.append(str(err)))
        page.goto(url)
        expect(page.get_by_test_id("machine-state")).to_have_text("idle", timeout=20000)
        page.get_by_test_id("btn-home").click()
        expect(page.locator("#homed")).to_contain_text("X homed", timeout=20000)
        page.locator("input[name=step][value='10']").check()
        page.get_by_test_id("jog-X+").click()
        expect(page.get_by_test_id("dro-X")).to_have_text("10.000", timeout=20000)
        # the jog is a job: it ends (its files written) after the axis arrived; a jog before is refused busy
        expect(page.get_by_test_id("machine-state")).to_have_text("idle", timeout=20000)
        page.get_by_test_id("jog-X-").click()
        expect(page.get_by_test_id("dro-X")).to_have_text("0.000", timeout=20000)
        page.locator("#file").set_input_files(str(program))
        expect(page.get_by_test_id("program-list")).to_contain_text("pocket.nc")
        page.screenshot(path=str(shots / "console-program-1600.png"), full_page=True)
        assert not errors, errors
        assert canvas_is_drawn(page)
        for view in ("view-top", "view-front", "view-iso"):
            page.locator(f"#{view}").click()
            assert canvas_is_drawn(page), view
        box = page.get_by_test_id("preview").bounding_box()
        page.mouse.move(box["x"] + 200, box["y"] + 200)
        page.mouse.down()
        page.mouse.move(box["x"] + 260, box["y"] + 230)  # turn the view by dragging
        page.mouse.up()
        assert canvas_is_drawn(page) and not errors, errors
        page.get_by_test_id("btn-start").click()
        expect(page.get_by_test_id("machine-state")).to_have_text("running", timeout=20000)
        page.get_by_test_id("btn-hold").click()
        expect(page.get_by_test_id("machine-state")).to_have_text("held", timeout=20000)
        page.screenshot(path=str(shots / "console-held-1600.png"), full_page=True)
        page.get_by_test_id("btn-resume").click()
        expect(page.get_by_test_id("job-history").locator("li", has_text="pocket.nc").first).to_contain_text(
            "completed", timeout=60000)
        expect(page.get_by_test_id("machine-state")).to_have_text("idle", timeout=20000)
        page.screenshot(path=str(shots / "console-done-1600.png"), full_page=True)
        phone = browser.new_page(viewport={"width": 390, "height": 844}, is_mobile=True, has_touch=True)
        phone.goto(url)
        expect(phone.get_by_test_id("machine-state")).to_have_text("idle", timeout=20000)
        width = phone.evaluate("() => document.documentElement.scrollWidth")
        assert width <= 390, f"the page is {width} px wide on a 390 px phone"
        phone.screenshot(path=str(shots / "console-phone-390.png"), full_page=True)
        browser.close()


def test_the_console_says_the_spindle_and_coolant_state_in_words(console):
    """status.spindle (signed commanded rpm) and status.coolant (per mode) as the read-out shows them."""
    from playwright.sync_api import expect, sync_playwright

    url, _ = console
    cases = [("spindleText(null)", "none"),
             ("spindleText({commanded_rpm: 0, actual_rpm: 0, at_speed: true})", "stopped"),
             ("spindleText({commanded_rpm: 12000, actual_rpm: 11994.6, at_speed: true})", "CW 12000 rpm, actual 11995"),
             ("spindleText({commanded_rpm: -800, actual_rpm: -300, at_speed: false})",
              "CCW 800 rpm, actual 300 (not at speed)"),
             ("spindleText({commanded_rpm: 800, fault: 'EMCY 0x2310'})", "fault: EMCY 0x2310"),
             ("coolantText(undefined)", "none"),
             ("coolantText({mist: false, flood: false})", "off"),
             ("coolantText({mist: true, flood: true})", "mist + flood"),
             ("coolantText({flood: true})", "flood")]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=BROWSER_ARGS)
        page = browser.new_page()
        page.goto(url)
        assert {expr: page.evaluate(expr) for expr, _ in cases} == dict(cases)
        expect(page.locator("#coolant")).to_have_text("none", timeout=20000)  # this machine has no coolant output
        browser.close()


def test_the_library_uploads_checks_selects_previews_starts_and_queues(console, tmp_path):
    """Upload to the daemon's library (a refused program shows its file:line and is not
    added), select a program (preview drawn from the library's text), start it by name,
    and queue it twice: the queue pane follows the daemon's events."""
    from playwright.sync_api import expect, sync_playwright

    url, daemon = console
    good, bad = tmp_path / "library-part.nc", tmp_path / "broken.nc"
    good.write_text(PART)
    bad.write_text("G21 G90\nG01 X10 Q3 F600\n")
    shots = shots_dir(tmp_path)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=BROWSER_ARGS)
        page = browser.new_page(viewport={"width": 1600, "height": 1100})
        errors: list[str] = []
        page.on("pageerror", lambda err: errors.append(str(err)))
        page.on("dialog", lambda dialog: dialog.accept())
        page.goto(url)
        expect(page.get_by_test_id("machine-state")).to_have_text("idle", timeout=20000)
        if "homed" not in (page.locator("#homed").text_content() or ""):
            page.get_by_test_id("btn-home").click()
            expect(page.locator("#homed")).to_contain_text("X homed", timeout=20000)
        page.locator("#file").set_input_files(str(bad))
        expect(page.get_by_test_id("check-result")).to_contain_text("broken.nc:2", timeout=20000)
        expect(page.get_by_test_id("check-result")).to_contain_text("not added")
        expect(page.get_by_test_id("program-list")).not_to_contain_text("broken.nc")
        # a refused program has no preview: the panel says so instead of counting its segments
        expect(page.get_by_test_id("selected-program")).to_have_text("broken.nc refused: no program selected")
        page.screenshot(path=str(shots / "library-refused-1600.png"), full_page=True)
        page.locator("#file").set_input_files(str(good))
        library = page.get_by_test_id("program-list")
        # 7 or 8 blocks: the first move (G00 Z5) is none when Z already holds at 5 (the other test ran first)
        expect(library.locator("li[data-program='library-part.nc']")).to_contain_text(
            re.compile(r"[78] blocks · X 0\.\.30 Y 0\.\.30 Z -1\.\.5 mm"), timeout=20000)
        expect(page.get_by_test_id("check-result")).to_contain_text(re.compile(r"library-part.nc checked: [78] blocks"))
        page.reload()  # nothing local left: the list and the preview come from the daemon's library
        expect(page.get_by_test_id("machine-state")).to_have_text("idle", timeout=20000)
        library.locator("li[data-program='library-part.nc'] button.pick").click()
        expect(library.locator("li.selected")).to_have_attribute("data-program", "library-part.nc")
        expect(page.get_by_test_id("selected-program")).to_contain_text("library-part.nc:")
        assert canvas_is_drawn(page)
        page.screenshot(path=str(shots / "library-selected-1600.png"), full_page=True)
        page.get_by_test_id("btn-start").click()
        expect(page.get_by_test_id("check-result")).to_contain_text("(checked when added)", timeout=20000)
        expect(page.get_by_test_id("job-history").locator("li", has_text="library-part.nc").first).to_contain_text(
            "completed", timeout=60000)
        expect(page.get_by_test_id("machine-state")).to_have_text("idle", timeout=20000)
        page.get_by_test_id("btn-queue-pause").click()
        expect(page.get_by_test_id("queue-state")).to_contain_text("paused", timeout=10000)
        page.get_by_test_id("btn-queue-add").click()
        page.get_by_test_id("btn-queue-add").click()
        expect(page.get_by_test_id("queue").locator("li")).to_have_count(2, timeout=10000)
        page.screenshot(path=str(shots / "library-queued-1600.png"), full_page=True)
        page.get_by_test_id("btn-queue-resume").click()
        expect(page.get_by_test_id("queue").locator("li")).to_have_count(0, timeout=60000)
        expect(page.get_by_test_id("machine-state")).to_have_text("idle", timeout=60000)
        expect(page.get_by_test_id("job-history").locator("li", has_text="library-part.nc")).to_have_count(3,
                                                                                                     timeout=60000)
        page.screenshot(path=str(shots / "library-queue-done-1600.png"), full_page=True)
        library.locator("li[data-program='library-part.nc'] button", has_text="✕").click()  # confirmed
        expect(library).not_to_contain_text("library-part.nc", timeout=10000)
        assert not errors, errors
        browser.close()
