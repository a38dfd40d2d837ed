"""Screenshots of the operator's page for docs/monitor.md, at 1400x1000: one sensor (the dryer
recording), eight sensors (a SKAB file diagnosed by a bank learned from its first 400 rows, as
benchmarks/skab/run.py learns it; without the SKAB data, an eight-sensor plant simulated from
tests/data/line8.jmlg), and the overview of a fleet of 20 simulated dryers.

    python benchmarks/page_screenshots.py [--data ../shared/data/skab/data] [--skab valve1_3]

Each recording is monitored to its end into a store in a temporary folder, the page is served from
it, an alarm is selected (so its evidence shows) and headless chromium (Playwright) takes the
picture once the page shows it (docs/monitor.md, "Screenshots of the page": the page's event stream
never ends, so a picture waits for what it shows, not for the network to go quiet). Times are shown
in UTC. Writes docs/figures/page-dryer.png, page-skab.png (or page-eight.png) and page-fleet.png.
Nothing of the SKAB data is written into this repository, only the picture.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from datetime import datetime, timedelta, timezone
from pathlib import Path

from playwright.sync_api import sync_playwright

from jmlgdsl.cli import main as jmlgdsl_main
from jmlgdsl.data import Columns, read_csv, write_columns
from jmlgdsl.monitor import Store
from jmlgdsl.page import Page

sys.path.insert(0, str(Path(__file__).resolve().parent / "skab"))
from run import NAMES, REPO, SENSORS, TRAIN, extend, learn  # noqa: E402

FIGURES = REPO / "docs" / "figures"
SKAB = REPO.parent / "shared" / "data" / "skab" / "data"
VIEWPORT = {"width": 1400, "height": 1000}
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
# the fleet's dryers: each unit's mode schedule over its 900 rows (default all normal), and what an
# operator has done with its alarms (None: nothing yet)
FLEET_START = datetime(2024, 5, 14, 6, 0, tzinfo=timezone.utc)
FLEET = {3: ("1-700:normal,701-900:fan", None), 7: ("1-820:normal,821-900:grill", None),
         8: ("1-300:normal,301-420:grill,421-900:normal", None),
         11: ("1-650:normal,651-900:fan", "acknowledge"), 15: ("1-200:normal,201-330:fan,331-900:normal", None),
         16: ("1-500:normal,501-900:fan", "shelve"), 19: ("1-880:normal,881-900:fan", None)}


def monitored(spec: Path, data: str | Path, store: Path, *options: str) -> Path:
    if jmlgdsl_main(["monitor", str(spec), "--source", str(data), "--store", str(store), "--no-follow", *options]):
        raise SystemExit(f"monitor {spec} on {data} failed")
    return store


def shoot(browser, store: Path, path: Path, alarm: int | None = None, window: tuple[int, int] | None = None):
    """A picture of the page of a store, once it shows its rows: zoomed to a past `window`, with
    `alarm` selected; with neither, the first view (a fleet's overview)."""
    page = Page(store, "127.0.0.1", 0).start()
    try:
        tab = browser.new_page(viewport=VIEWPORT, timezone_id="UTC")
        tab.goto(page.url)
        tab.wait_for_selector("#alarmlist tr[data-alarm], #unitlist tr")
        if window is not None:  # a past window, as zoom and pan would show it
            with tab.expect_response(lambda r: "api/rows?first=" in r.url):
                tab.evaluate(f"moveTo({window[0]}, {window[1]})")
            tab.wait_for_timeout(300)
        if alarm is not None:
            tab.click(f"#alarmlist tr[data-alarm='{alarm}'] td:first-child")
            tab.wait_for_selector("#evidence .bar")
        tab.screenshot(path=str(path))
        tab.close()
    finally:
        page.stop()
    print(f"wrote {path}")


def skab_store(data: Path, stem: str, folder: Path) -> tuple[Path, int]:
    """A store of one SKAB file, diagnosed by its strict bank with the cross-validated setting, and
    the alarm to show: the first one raised after the learning rows."""
    chosen = json.loads((REPO / "benchmarks" / "skab" / "results" / "strict" / "summary.json").read_text())["chosen"]
    setting = chosen[stem]
    part, name = stem.split("_", 1)
    source = data / part / f"{name}.csv"
    recording = read_csv(source, Columns(outputs=SENSORS))
    train = folder / "train.csv"
    write_columns(train, {s: recording.y[:TRAIN, i] for i, s in enumerate(NAMES)})
    learn("normal", [train], folder / "normal.jmlg", 1, f"skab_{stem}")
    spec = folder / f"{stem}.jmlg"
    spec.write_text(extend((folder / "normal.jmlg").read_text(), None, setting["scale"], setting["stay"], 0.99))
    store = monitored(spec, source, folder / "skab.db", "--healthy", "normal", "--threshold",
                      str(setting["threshold"]), "--persistence", str(setting["persistence"]))
    with Store(store) as opened:
        alarms = [a for a in opened.alarms(opened.run().id) if a.raised_t > TRAIN]
    return store, alarms[0].id


def eight_store(folder: Path) -> tuple[Path, int]:
    """Without the SKAB data: an eight-sensor plant simulated with a leak at rows 301-500."""
    spec, data = REPO / "tests" / "data" / "line8.jmlg", folder / "line8.csv"
    if jmlgdsl_main(["simulate", str(spec), "--modes", "1-300:normal,301-500:leak,501-700:normal", "--seed", "1",
                     "-o", str(data)]):
        raise SystemExit(f"simulate {spec} failed")
    return monitored(spec, data, folder / "line8.db"), 1


def clocked(data: Path, start: datetime):
    """A simulated file's `time` (seconds from 1) as a `datetime` column from `start`."""
    lines = data.read_text().splitlines()
    rows = [(start + timedelta(seconds=float(line.split(",", 1)[0]) - 1)).strftime("%Y-%m-%d %H:%M:%S")
            + "," + line.split(",", 1)[1] for line in lines[1:]]
    data.write_text("\n".join(["datetime," + lines[0].split(",", 1)[1], *rows]) + "\n")


def fleet_store(folder: Path) -> Path:
    """A fleet of 20 dryers (pump01..pump20) simulated for 900 s each, some with faults (FLEET), a few
    of whose alarms an operator has acknowledged or shelved; an alarm needs P(not normal) > 0.9 for
    5 s, as a plant would set it to keep a fleet's list short."""
    (folder / "fleet").mkdir()
    spec = REPO / "specs" / "dryer.jmlg"
    for i in range(1, 21):
        data = folder / "fleet" / f"pump{i:02d}.csv"
        if jmlgdsl_main(["simulate", str(spec), "--modes", FLEET.get(i, ("1-900:normal", None))[0], "--seed", str(i),
                         "-o", str(data)]):
            raise SystemExit(f"simulate {spec} failed")
        clocked(data, FLEET_START)
    store = monitored(spec, folder / "fleet" / "{unit}.csv", folder / "fleet.db", "--units", "pump01..pump20",
                      "--threshold", "0.9", "--persistence", "5")
    with Store(store) as opened:
        for i, (_, action) in FLEET.items():
            run = opened.run(unit=f"pump{i:02d}")
            for alarm in opened.alarms(run.id) if action else ():
                opened.act(run.id, alarm.id, action, "ann", "sensor under repair" if action == "shelve" else None)
    return store


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=SKAB if SKAB.is_dir() else None,
                        help="the SKAB data folder (its data/ folder; default ../shared/data/skab/data where it "
                             "exists): the eight-sensor picture from SKAB, not from a simulated plant")
    parser.add_argument("--skab", default="valve1_3", help="which SKAB file, FOLDER_NAME (default valve1_3)")
    args = parser.parse_args(argv)
    data = None if args.data is None else Path(os.path.relpath(args.data.resolve(), REPO))
    os.chdir(REPO)  # the pictures show the sources' paths from the repository's root
    folder = Path(tempfile.mkdtemp(prefix="page-screenshots-"))
    try:
        dryer = monitored(Path("specs/dryer.jmlg"), Path("examples/dryer_seq1.csv"), folder / "dryer.db")
        shots = [(dryer, FIGURES / "page-dryer.png", 1, (40, 400))]
        if data is not None:
            store, alarm = skab_store(data, args.skab, folder)
            shots.append((store, FIGURES / "page-skab.png", alarm, (500, 1148)))
        else:
            store, alarm = eight_store(folder)
            shots.append((store, FIGURES / "page-eight.png", alarm, None))
        shots.append((fleet_store(folder), FIGURES / "page-fleet.png", None, None))
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=shutil.which("chromium") or "/usr/bin/chromium",
                                                 args=FLAGS)
            for store, path, alarm, window in shots:
                shoot(browser, store, path, alarm, window)
            browser.close()
    finally:
        shutil.rmtree(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
