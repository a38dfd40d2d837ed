"""The operator's page over HTTP (no browser: tests/test_page_browser.py drives one): the JSON it
reads from a store, windows of rows, alarms acknowledged and shelved into the store (and refused when
they do not apply, lack the token or come from elsewhere), an address off this machine refused
without a token, a store of the previous schema brought up to date, and the band of two standard
deviations that holds the readings as often as a Gaussian says."""

import json
import sqlite3
import subprocess
import urllib.error
import urllib.request

import numpy as np
import pytest
from conftest import ROOT, jmlgdsl_command
from monitor_servers import DATA, SPEC, WAIT, exported, expected_table, free_port

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.diagnosis.prediction import predictive_sd
from jmlgdsl.monitor import Store
from jmlgdsl.page import Page, PageError


def get(page, path):
    with urllib.request.urlopen(page.url + path, timeout=WAIT) as answer:
        return json.load(answer)


def post(page, path, body, headers=None, kind="application/json"):
    request = urllib.request.Request(page.url + path, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": kind, **(headers or {})})
    try:
        with urllib.request.urlopen(request, timeout=WAIT) as answer:
            return answer.status, json.load(answer)
    except urllib.error.HTTPError as error:
        return error.code, json.load(error)


def test_the_run_and_windows_of_rows_come_from_the_store(page):
    run = get(page, "api/run")
    assert run["modes"] == ["normal", "fan", "grill", "fan_grill"] and run["outputs"] == ["temp"]
    assert run["descriptions"]["fan"] == "Faulty fan" and run["units"]["temp"] == "degC"
    assert run["healthy"] == ["normal"] and run["token_required"] is False
    live = get(page, "api/rows")
    assert live["t"] == list(range(701, 1001)) and live["map_mode"][-1] == "fan"
    thinned = get(page, "api/rows?first=1&last=1000&limit=100")
    assert thinned["t"] == list(range(1, 1001, 10))
    after = get(page, "api/rows?after=995")
    assert after["t"] == [996, 997, 998, 999, 1000]
    model = jmlgdsl.load(SPEC)
    data = jmlgdsl.read_csv(str(DATA), model)
    result = jmlgdsl.filter(model, data.y, data.u)
    assert after["posterior"][-1] == result.mode_posterior[-1].tolist() and after["y"][-1] == data.y[-1].tolist()
    assert after["y_sd"][0][0] > 0 and get(page, "api/rows?first=1&last=1")["y_sd"] == [[None]]


def test_alarms_are_acknowledged_and_shelved_into_the_store_and_survive_a_new_page(page, store):
    alarms = get(page, "api/alarms")
    assert [(a["id"], a["mode"], a["state"]) for a in alarms] == [
        (3, "grill", "active, unacknowledged"), (2, "grill", "cleared, unacknowledged"),
        (1, "fan", "cleared, unacknowledged")]
    status, answer = post(page, "api/alarms/3/acknowledge", {"who": "ann"})
    assert status == 200 and answer[0]["state"] == "active, acknowledged" and answer[0]["acknowledged"]["who"] == "ann"
    assert post(page, "api/alarms/3/acknowledge", {"who": "bob"}) == (400, {"error": "alarm 3 is acknowledged already"})
    assert post(page, "api/alarms/2/shelve", {"who": "ann"}) == (400, {"error": "shelving needs a reason"})
    assert post(page, "api/alarms/2/acknowledge", {"who": " "}) == (400, {"error": "say who acts (a name or initials)"})
    assert post(page, "api/alarms/9/acknowledge", {"who": "ann"}) == (400, {"error": "run 1 has no alarm 9"})
    status, answer = post(page, "api/alarms/2/shelve", {"who": "ann", "reason": "sensor being replaced"})
    assert answer[1]["state"] == "shelved" and answer[1]["shelved"]["reason"] == "sensor being replaced"
    again = Page(store, "127.0.0.1", 0).start()
    try:
        states = {a["id"]: a["state"] for a in get(again, "api/alarms")}
    finally:
        again.stop()
    assert states == {3: "active, acknowledged", 2: "shelved", 1: "cleared, unacknowledged"}
    with sqlite3.connect(store) as db:
        assert db.execute("SELECT alarm, who, kind, reason FROM action ORDER BY id").fetchall() == [
            (3, "ann", "acknowledge", None), (2, "ann", "shelve", "sensor being replaced")]


def test_an_action_must_be_json_from_the_page_itself(page):
    assert post(page, "api/alarms/3/acknowledge", {"who": "ann"}, kind="text/plain")[0] == 403
    assert post(page, "api/alarms/3/acknowledge", {"who": "ann"}, {"Origin": "http://elsewhere.example"})[0] == 403
    assert get(page, "api/alarms")[0]["acknowledged"] is None


def test_with_a_token_an_action_needs_it_and_reading_does_not(store):
    page = Page(store, "127.0.0.1", 0, token="s3cret").start()
    try:
        assert get(page, "api/run")["token_required"] is True
        assert post(page, "api/alarms/3/acknowledge", {"who": "ann"}) == (
            401, {"error": "this page needs its token to act on alarms"})
        assert post(page, "api/alarms/3/acknowledge", {"who": "ann"}, {"Authorization": "Bearer wrong"})[0] == 401
        assert post(page, "api/alarms/3/acknowledge", {"who": "ann"}, {"Authorization": "Bearer s3cret"})[0] == 200
        assert "s3cret" not in urllib.request.urlopen(page.url, timeout=WAIT).read().decode()
    finally:
        page.stop()


def test_an_address_off_this_machine_needs_a_token(store, tmp_path):
    with pytest.raises(PageError, match="give a token with --http-token-env or --http-token-file"):
        Page(store, "0.0.0.0", 0)
    done = subprocess.run([*jmlgdsl_command(), "dashboard", store, "--http", f"0.0.0.0:{free_port()}"],
                          capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2 and "the page may be reached from other machines there; give a token" in done.stderr
    done = subprocess.run([*jmlgdsl_command(), "monitor", SPEC, "--source", str(DATA), "--store",
                           str(tmp_path / "new.db"), "--no-follow", "--http", f"0.0.0.0:{free_port()}"],
                          capture_output=True, text=True, timeout=WAIT)
    assert done.returncode == 2 and "give a token" in done.stderr and not (tmp_path / "new.db").exists()


def test_the_dashboard_command_serves_a_store_until_stopped(store):
    port = free_port()
    process = subprocess.Popen([*jmlgdsl_command(), "dashboard", store, "--http", f"127.0.0.1:{port}"],
                               stderr=subprocess.PIPE, text=True)
    try:
        assert process.stderr.readline().strip() == f"the operator's page: http://127.0.0.1:{port}/"
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=WAIT) as answer:
            assert "default-src 'self'" in answer.headers["Content-Security-Policy"]
            assert b'<script src="page.js" defer></script>' in answer.read()
        process.terminate()
        assert process.wait(WAIT) == 0
    finally:
        process.kill()


def test_a_store_of_the_first_schema_is_brought_up_to_date_and_resumed(tmp_path):
    store = str(tmp_path / "old.db")
    first = tmp_path / "first.csv"
    lines = DATA.read_text().splitlines(keepends=True)
    first.write_text("".join(lines[:501]))
    assert main(["monitor", SPEC, "--source", str(first), "--store", store, "--no-follow"]) == 0
    with sqlite3.connect(store) as db:  # as the first schema had it: no new columns, no actions
        db.execute("DROP INDEX run_unit")
        for table, column in (("run", "descriptions"), ("run", "units"), ("run", "unit"), ("result", "y_sd"),
                              ("result", "evidence_mode"), ("result", "evidence"), ("alarm", "mode")):
            db.execute(f"ALTER TABLE {table} DROP COLUMN {column}")
        db.execute("DROP TABLE action")
        db.execute("UPDATE meta SET value = '1' WHERE key = 'schema'")
    with open(first, "a") as out:
        out.writelines(lines[501:])
    assert main(["monitor", SPEC, "--source", str(first), "--store", store, "--no-follow"]) == 0
    assert exported(tmp_path, store) == expected_table(tmp_path)
    with Store(store) as opened:
        assert opened.run().descriptions == {} and opened.alarms(1)[-1].mode == "grill"


def test_the_band_holds_the_readings_as_often_as_a_gaussian_says():
    # One mode, three outputs of two states: the standardised residuals (y - y_pred) / sd over 2,000
    # rows have variance 1 within 4 of its standard errors, sqrt(2 / 2000) each (chi-square).
    model = jmlgdsl.load(str(ROOT / "specs" / "cstr4.jmlg"))
    sim = jmlgdsl.simulate(model, 2001, seed=7, modes="1-2001:" + model.modes[0])
    result = jmlgdsl.filter(model, sim.y, sim.u)
    z = np.array([(sim.y[t] - result.y_pred[t]) / predictive_sd(
        model, result.mode_posterior[t - 1], result.state_mean[t - 1], result.state_cov[t - 1], sim.u[t])
        for t in range(1, 2001)])
    assert np.abs(z.var(axis=0) - 1).max() < 4 * np.sqrt(2 / 2000)
