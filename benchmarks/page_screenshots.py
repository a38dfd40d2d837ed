"""Screenshots of the operator's page for docs/monitor.md: the dryer recording, and a SKAB file
diagnosed by a bank learned from its first 400 rows (as benchmarks/skab/run.py learns it).

    python benchmarks/page_screenshots.py [--data ../shared/data/skab/data] [--skab valve1_3]

Each recording is monitored to its end into a store in a temporary folder, the page is served from
it, an alarm is selected (so its evidence shows) and headless chromium (Playwright) takes the
picture: docs/figures/page-dryer.png and, with --data, docs/figures/page-skab.png. Nothing of the
SKAB data is written into this repository, only the picture.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

from playwright.sync_api import sync_playwright

from jmlgdsl.cli import main as jmlgdsl_main
from jmlgdsl.data import Columns, read_csv, write_columns
from jmlgdsl.monitor import Store
from jmlgdsl.page import Page

sys.path.insert(0, str(Path(__file__).resolve().parent / "skab"))
from run import NAMES, REPO, SENSORS, TRAIN, extend, learn  # noqa: E402

FIGURES = REPO / "docs" / "figures"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def monitored(spec: Path, data: Path, store: Path, *options: str) -> Path:
    if jmlgdsl_main(["monitor", str(spec), "--source", str(data), "--store", str(store), "--no-follow", *options]):
        raise SystemExit(f"monitor {spec} on {data} failed")
    return store


def shoot(browser, store: Path, alarm: int, path: Path, window: tuple[int, int] | None = None):
    page = Page(store, "127.0.0.1", 0).start()
    try:
        tab = browser.new_page(viewport={"width": 1500, "height": 950})
        tab.goto(page.url)
        tab.wait_for_selector(f"#alarmlist tr[data-alarm='{alarm}']")
        if window is not None:  # a past window, as zoom and pan would show it
            with tab.expect_response(lambda r: "api/rows?first=" in r.url):
                tab.evaluate(f"moveTo({window[0]}, {window[1]})")
            tab.wait_for_timeout(300)
        tab.click(f"#alarmlist tr[data-alarm='{alarm}']")
        tab.wait_for_selector("#evidence .bar")
        tab.screenshot(path=str(path), full_page=True)
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="the SKAB data folder (its data/ folder): also the SKAB picture")
    parser.add_argument("--skab", default="valve1_3", help="which SKAB file, FOLDER_NAME (default valve1_3)")
    args = parser.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="page-screenshots-"))
    try:
        dryer = monitored(REPO / "specs" / "dryer.jmlg", REPO / "examples" / "dryer_seq1.csv", folder / "dryer.db")
        stores = [(dryer, 1, FIGURES / "page-dryer.png", (40, 400))]
        if args.data is not None:
            store, alarm = skab_store(args.data, args.skab, folder)
            stores.append((store, alarm, FIGURES / "page-skab.png", None))
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=shutil.which("chromium") or "/usr/bin/chromium",
                                                 args=FLAGS)
            for store, alarm, path, window in stores:
                shoot(browser, store, alarm, path, window)
            browser.close()
    finally:
        shutil.rmtree(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
