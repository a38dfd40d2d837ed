"""The operator's page in a real headless browser (Debian's chromium, driven by Playwright): a
finished store's page shows the mode, the alarms and the evidence, and a past window when zoomed;
a row published to the broker
shows its mode on the page within 2 s; an acknowledgement clicked on the page is in the store and
still there after the monitor is killed and started again; markup in a spec's mode description is
shown as text and never run. Screenshots go to the test's folder (JMLGDSL_SCREENSHOTS names another)."""

import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
from conftest import jmlgdsl_command
from monitor_servers import (DATA, MOSQUITTO, NO_MOSQUITTO, SPEC, WAIT, Brokers, free_port, publish, query, samples,
                             until)

from jmlgdsl.cli import main

sync_api = pytest.importorskip("playwright.sync_api", reason="Playwright is not installed (pip install '.[test]')")
CHROMIUM = shutil.which("chromium") or next((p for p in ("/usr/bin/chromium",) if os.access(p, os.X_OK)), None)
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium browser on PATH (.ci/run installs it: "
                                                         "apt-get install chromium)")
# a closed network: no background requests, no first-run pages, no sandbox (the tests may run as root)
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        yield launched
        launched.close()


@pytest.fixture
def tab(browser):
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    errors = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    yield page
    page.close()
    assert errors == []


def shows(tab, selector, text, timeout=WAIT * 1000):
    """Wait until an element's text is `text` (or matches it), through Playwright's own script: the
    page's Content-Security-Policy forbids the eval a string predicate would need."""
    sync_api.expect(tab.locator(selector)).to_have_text(text, timeout=timeout)


def screenshot(tab, tmp_path, name):
    folder = Path(os.environ.get("JMLGDSL_SCREENSHOTS") or tmp_path)
    folder.mkdir(parents=True, exist_ok=True)
    tab.screenshot(path=str(folder / name), full_page=True)


def serve(store, *extra):
    """`jmlgdsl dashboard STORE` on a free port: (process, url)."""
    port = free_port()
    process = subprocess.Popen([*jmlgdsl_command(), "dashboard", store, "--http", f"127.0.0.1:{port}", *extra],
                               stderr=subprocess.PIPE, text=True)
    assert process.stderr.readline().startswith("the operator's page: ")
    return process, f"http://127.0.0.1:{port}/"


def test_a_finished_store_shows_its_mode_alarms_and_evidence(tab, tmp_path):
    store = str(tmp_path / "dryer.db")
    assert main(["monitor", SPEC, "--source", str(DATA), "--store", store, "--no-follow"]) == 0
    process, url = serve(store)
    try:
        tab.goto(url)
        shows(tab, "#status", re.compile(r"^row 1000\b"))
        assert tab.text_content("#mode") == "fan" and tab.text_content("#description") == "Faulty fan"
        assert tab.locator("#alarmlist tr").count() == 3
        assert tab.text_content("#alarmlist tr[data-alarm='3'] td.state .what") == "active, unacknowledged"
        tab.click("#alarmlist tr[data-alarm='3']")
        shows(tab, "#whyfor", "alarm 3: grill")
        assert tab.locator("#evidence .bar[data-output='temp'] .nats").text_content() != ""
        box = tab.locator("#strip").bounding_box()
        tab.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        with tab.expect_response(lambda response: "api/rows?first=" in response.url) as zoomed:
            tab.mouse.wheel(0, -300)  # zoom in around the middle of the live window (rows 701-1000)
        window = zoomed.value.json()["t"]
        assert 701 < window[0] < window[-1] < 1000 and tab.get_attribute("#live", "class") == ""
        with tab.expect_response(lambda response: response.url.endswith("api/rows")):
            tab.click("#live")
        assert tab.get_attribute("#live", "class") == "on"
        screenshot(tab, tmp_path, "page-dryer.png")
    finally:
        process.terminate()
        process.wait(WAIT)


@pytest.mark.skipif(MOSQUITTO is None, reason=NO_MOSQUITTO)
def test_published_rows_appear_live_and_an_acknowledgement_survives_a_restart(tab, tmp_path):
    brokers = Brokers(tmp_path)
    port, store = brokers(), str(tmp_path / "dryer.db")
    recording = samples()

    def monitor():
        http = free_port()
        process = subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--source", f"mqtt://127.0.0.1:{port}/dryer",
                                    "--store", store, "--http", f"127.0.0.1:{http}"], stderr=subprocess.PIPE, text=True)
        until(lambda: (query(store, "SELECT count(*) FROM event WHERE kind = 'connect'") or 0) >= 1
              + (query(store, "SELECT count(*) FROM event WHERE kind = 'resume'") or 0), "the monitor to connect",
              process)
        return process, f"http://127.0.0.1:{http}/"

    first = second = None
    try:
        first, url = monitor()
        publish(port, recording[:100])
        until(lambda: query(store, "SELECT count(*) FROM result") == 100, "100 rows stored", first)
        tab.goto(url)
        shows(tab, "#status", re.compile(r"^row 100\b"))
        assert tab.text_content("#mode") == "fan"
        sent = time.monotonic()
        publish(port, recording[100:101])
        shows(tab, "#status", re.compile(r"^row 101\b"), timeout=2000)
        shown = time.monotonic() - sent
        assert shown < 2, f"row 101 took {shown:.2f} s to show"
        assert tab.text_content("#mode") == "fan"

        tab.fill("#who", "ann")
        tab.click("#alarmlist tr[data-alarm='1'] button:text('Acknowledge')")
        shows(tab, "#alarmlist tr[data-alarm='1'] td.state .what", "active, acknowledged")
        assert query(store, "SELECT who || ' ' || kind FROM action WHERE alarm = 1") == "ann acknowledge"
        screenshot(tab, tmp_path, "page-live.png")

        first.send_signal(signal.SIGKILL)
        first.wait(WAIT)
        second, url = monitor()
        publish(port, recording[101:120])
        until(lambda: query(store, "SELECT count(*) FROM result") == 120, "120 rows stored", second)
        tab.goto(url)
        shows(tab, "#status", re.compile(r"^row 120\b"))
        assert tab.text_content("#alarmlist tr[data-alarm='1'] td.state .what") == "active, acknowledged"
        assert tab.locator("#alarmlist tr[data-alarm='1'] button:text('Acknowledge')").count() == 0
    finally:
        for process in (first, second):
            if process is not None:
                process.kill()
        for broker in list(brokers.running):
            brokers.stop(broker)


def test_markup_in_a_spec_is_shown_as_text(tab, tmp_path):
    markup = "<script>window.owned = 1</script><img src=x onerror='window.owned = 2'><b>bold</b>"
    spec = tmp_path / "dryer.jmlg"
    spec.write_text(Path(SPEC).read_text().replace('"Faulty fan"', f'"{markup}"'))
    store = str(tmp_path / "dryer.db")
    assert main(["monitor", str(spec), "--source", str(DATA), "--store", store, "--no-follow"]) == 0
    process, url = serve(store)
    try:
        tab.goto(url)
        shows(tab, "#mode", "fan")
        assert tab.text_content("#description") == markup
        assert tab.locator("#description *").count() == 0 and tab.locator("b").count() == 0
        assert tab.evaluate("window.owned") is None
        screenshot(tab, tmp_path, "page-markup.png")
    finally:
        process.terminate()
        process.wait(WAIT)
