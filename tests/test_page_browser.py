"""The operator's page in a real headless browser (Debian's chromium, driven by Playwright): a
finished store's page shows the mode, the alarms (with the mode the plant is in now) and the
evidence, and a past window when zoomed, in colours that never make a mode look like an alarm; clock
times show as local time with the zone, the row on hover; with eight sensors the evidence of a
clicked alarm is in sight, the alarm's buttons inside its card, zooming out stops at the data and
the alarm's shading has no stripes; a fleet opens on its units worst first; a row published to the
broker shows its mode on the page within 2 s; an acknowledgement clicked on the page is in the store
and still there after the monitor is killed and started again; markup in a spec's mode description
is shown as text and never run. Screenshots go to the test's folder (JMLGDSL_SCREENSHOTS names
another)."""

import colorsys
import os
import re
import shutil
import signal
import subprocess
import time
from datetime import datetime, timedelta
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import pytest
from conftest import jmlgdsl_command
from monitor_servers import (DATA, LINES, MOSQUITTO, NO_MOSQUITTO, SPEC, WAIT, Brokers, free_port, publish, query,
                             samples, until)

from jmlgdsl.cli import main
from jmlgdsl.monitor import Store

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


def swatch(tab, selector) -> str:
    return tab.eval_on_selector(selector, "e => e.style.getPropertyValue('--swatch')")


def alarm_like(colour: str) -> bool:
    """Whether a CSS colour (#rrggbb or rgb(r, g, b)) is a red, orange or amber, the alarms' colours:
    a saturated hue within 60 degrees of red."""
    if colour.startswith("#"):
        rgb = [int(colour[i:i + 2], 16) / 255 for i in (1, 3, 5)]
    else:
        rgb = [int(v) / 255 for v in re.findall(r"\d+", colour)[:3]]
    hue, lightness, saturation = colorsys.rgb_to_hls(*rgb)
    return saturation > 0.3 and (hue * 360 < 60 or hue * 360 > 330)


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
        # raised in grill, the plant in fan since: the list says both
        assert tab.text_content("#alarmlist tr[data-alarm='3'] td.mode .raised") == "grill"
        assert tab.text_content("#alarmlist tr[data-alarm='3'] td.mode .now") == "now fan"
        assert tab.locator("#alarmlist tr[data-alarm='1'] td.mode .now").count() == 0  # cleared: no mode now
        # modes in colours of their own, none of them an alarm's red or amber; alarms with an icon
        for colour in tab.eval_on_selector_all("#legend span", "spans => spans.map(s => s.style.getPropertyValue("
                                                               "'--swatch'))") + [swatch(tab, "#mode")]:
            assert not alarm_like(colour), colour
        assert tab.eval_on_selector("#mode", "m => getComputedStyle(m).backgroundColor") == "rgba(0, 0, 0, 0)"
        assert alarm_like(tab.eval_on_selector("#alarmlist tr[data-alarm='3'] .badge",
                                               "b => getComputedStyle(b).backgroundColor"))
        assert tab.eval_on_selector("#alarmlist tr[data-alarm='3'] .badge",
                                    "b => getComputedStyle(b, '::before').content") == '"!"'
        tab.click("#alarmlist tr[data-alarm='3'] td:first-child")
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


def test_clock_times_show_as_local_time_with_its_zone_and_the_row_on_hover(browser, tmp_path):
    """The dryer recording stamped from 2020-03-09 11:14:34 UTC, one row a second, seen from Berlin
    (UTC+01:00 in March): row t is at 12:14:34 + (t - 1) s local time."""
    start = datetime(2020, 3, 9, 11, 14, 34)
    lines = ["datetime," + LINES[0].split(",", 1)[1]]
    for line in LINES[1:]:
        t, rest = line.split(",", 1)
        lines.append(f"{start + timedelta(seconds=int(t) - 1)},{rest}")
    data, store = tmp_path / "clock.csv", str(tmp_path / "clock.db")
    data.write_text("".join(lines))
    assert main(["monitor", SPEC, "--source", str(data), "--store", store, "--no-follow"]) == 0
    process, url = serve(store)
    context = browser.new_context(viewport={"width": 1400, "height": 900}, timezone_id="Europe/Berlin")
    try:
        tab = context.new_page()
        tab.goto(url)
        shows(tab, "#status", "row 1000 · 2020-03-09 12:31:13")
        assert "Europe/Berlin (UTC+01:00)" in tab.text_content("#zone")
        cells = tab.locator("#alarmlist tr[data-alarm='1'] td")  # raised at row 72, cleared at row 368
        assert (cells.nth(1).text_content(), cells.nth(2).text_content()) == ("12:15:45", "12:20:41")
        assert cells.nth(1).get_attribute("title") == "row 72 · 2020-03-09 12:15:45 Europe/Berlin (UTC+01:00)"
        assert tab.text_content("#alarmlist tr[data-alarm='3'] td:nth-child(2)") == "12:23:10"
        # the live window, rows 701-1000 (12:26:14 to 12:31:13): a tick on each whole minute, at its row
        ticks = tab.locator("#axis span")
        assert ticks.all_text_contents() == ["12:27", "12:28", "12:29", "12:30", "12:31"]
        assert [int(ticks.nth(i).get_attribute("data-t")) for i in range(5)] == [747, 807, 867, 927, 987]
        box = tab.locator("#strip").bounding_box()
        tab.mouse.move(box["x"] + 74 + (850 - 701 + 0.5) / 300 * (box["width"] - 74), box["y"] + 20)
        assert tab.text_content("#hover").startswith("row 850 · 2020-03-09 12:28:43 Europe/Berlin (UTC+01:00) · ")
        screenshot(tab, tmp_path, "page-clock.png")
    finally:
        context.close()
        process.terminate()
        process.wait(WAIT)


def test_eight_sensors_keep_the_evidence_in_sight_and_the_window_on_the_data(browser, tmp_path):
    """An eight-sensor plant (tests/data/line8.jmlg) with a leak at rows 301-500, on a screen of
    1400x1000: the page's first view is the live window, rows 301-600."""
    spec = str(Path(__file__).parent / "data" / "line8.jmlg")
    data, store = tmp_path / "line8.csv", str(tmp_path / "line8.db")
    assert main(["simulate", spec, "--modes", "1-300:normal,301-500:leak,501-600:normal", "--seed", "1",
                 "-o", str(data)]) == 0
    assert main(["monitor", spec, "--source", str(data), "--store", store, "--no-follow"]) == 0
    with Store(store, create=False) as opened:
        assert [(a.raised_t, a.cleared_t) for a in opened.alarms(1)] == [(301, 501)]
    process, url = serve(store)
    tab = browser.new_page(viewport={"width": 1400, "height": 1000})
    try:
        tab.goto(url)
        shows(tab, "#status", re.compile(r"^row 600\b"))
        for width in (1200, 1400):  # the alarm's buttons inside its card, on a narrower screen too
            tab.set_viewport_size({"width": width, "height": 1000})
            card = tab.locator("#alarms").bounding_box()
            for control in tab.locator("#alarms button, #alarms input, #alarms .badge").all():
                box = control.bounding_box()
                assert card["x"] <= box["x"] and box["x"] + box["width"] <= card["x"] + card["width"], width
        tab.click("#alarmlist tr[data-alarm='1'] td:first-child")
        shows(tab, "#whyfor", "alarm 1: leak")
        tab.wait_for_selector("#evidence .bar")
        why = tab.locator("#why").bounding_box()
        assert 0 <= why["y"] and why["y"] + why["height"] <= 1000, why  # in sight, not below the fold

        # the shading of rows 301-500 under the alarm: one colour along the top of a plot (no stripes)
        width = tab.eval_on_selector("#plots canvas", "c => c.width")
        left, right = (round(74 + (t - 301 + 0.5) / 300 * (width - 74)) for t in (320, 480))
        top = tab.eval_on_selector("#plots canvas", f"""c => {{
            const d = c.getContext("2d").getImageData({left}, 1, {right - left}, 1).data, seen = new Set();
            for (let i = 0; i < d.length; i += 4) seen.add(Array.from(d.slice(i, i + 4)).join());
            return [...seen]; }}""")
        assert len(top) == 1, top

        # zooming out stops at the rows there are
        box = tab.locator("#strip").bounding_box()
        tab.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        for _ in range(6):
            with tab.expect_response(lambda response: "api/rows?first=" in response.url) as zoomed:
                tab.mouse.wheel(0, 300)
        window = parse_qs(urlsplit(zoomed.value.url).query)
        assert (window["first"], window["last"]) == (["1"], ["600"])
        assert 1 <= int(tab.locator("#axis span").first.get_attribute("data-t"))
        assert int(tab.locator("#axis span").last.get_attribute("data-t")) <= 600
        screenshot(tab, tmp_path, "page-eight.png")
    finally:
        tab.close()
        process.terminate()
        process.wait(WAIT)


def test_a_fleet_opens_on_its_units_worst_first(tab, tmp_path):
    """Five units cut from the dryer recording (its alarms: fan at rows 72-368, grill at 370-371,
    grill from 517 on): pump01 rows 1-60 (no alarm), pump02 rows 1-400 (both alarms cleared, not
    acknowledged), pump03 all (grill active), pump04 all with the grill alarm acknowledged, pump05
    rows 1-200 (fan active)."""
    cut = {"pump01": 60, "pump02": 400, "pump03": 1000, "pump04": 1000, "pump05": 200}
    (tmp_path / "data").mkdir()
    for unit, rows in cut.items():
        (tmp_path / "data" / f"{unit}.csv").write_text("".join(LINES[:rows + 1]))
    store = str(tmp_path / "fleet.db")
    assert main(["monitor", SPEC, "--source", str(tmp_path / "data" / "{unit}.csv"), "--units", "pump01..pump05",
                 "--store", store, "--no-follow"]) == 0
    with Store(store, create=False) as opened:
        run = opened.run(unit="pump04").id
        grill = opened.alarms(run)[-1].id  # an alarm's id is the store's, not the run's
        opened.act(run, grill, "acknowledge", "ann")
    process, url = serve(store)
    try:
        tab.goto(url)
        tab.wait_for_selector("#unitlist tr")
        assert tab.is_hidden("#unitview") and tab.is_visible("#overview")
        rows = tab.locator("#unitlist tr")
        listed = [(rows.nth(i).get_attribute("data-unit"), rows.nth(i).locator("td.attention").text_content(),
                   rows.nth(i).locator("td.mode").text_content(), rows.nth(i).locator("td.alarms .badge").count())
                  for i in range(rows.count())]
        assert listed == [("pump03", "active, unacknowledged", "fan", 3),
                          ("pump05", "active, unacknowledged", "fan", 1),
                          ("pump04", "active, acknowledged", "fan", 3),
                          ("pump02", "cleared, unacknowledged", "normal", 2),
                          ("pump01", "", "normal", 0)]
        assert tab.text_content("#unitlist tr[data-unit='pump05'] td.alarms .badge") == "fan since t 72"
        screenshot(tab, tmp_path, "page-fleet.png")
        with tab.expect_navigation():
            tab.click("#unitlist tr[data-unit='pump04'] td.mode")
        assert tab.url == f"{url}?unit=pump04"
        shows(tab, "#status", re.compile(r"^row 1000\b"))
        assert tab.text_content(f"#alarmlist tr[data-alarm='{grill}'] td.state .what") == "active, acknowledged"
        with tab.expect_navigation():
            tab.click("#allunits")
        tab.wait_for_selector("#unitlist tr")
        assert tab.locator("#unitlist tr").first.get_attribute("data-unit") == "pump03"
    finally:
        process.terminate()
        process.wait(WAIT)
