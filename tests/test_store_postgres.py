"""A monitor's store in PostgreSQL, against a real server these tests start on 127.0.0.1 (Debian's
postgresql, which .ci/run installs; they skip without one): the exported table equals `jmlgdsl run
-o`, a monitor killed with SIGKILL mid-file and started again loses and repeats no row, the page's
API reads and acts on the store, monitors in schemas of their own write one database at once, as do
the Ray shards of a fleet's monitor, and a
wrong password, or one in the URL, is refused with a message that names the store and not the
password."""

import glob
import json
import os
import pwd
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request

import pytest
from conftest import jmlgdsl_command
from monitor_servers import DATA, SPEC, WAIT, Receiver, free_port, killed_mid_file

from jmlgdsl.cli import main
from jmlgdsl.monitor import Store
from jmlgdsl.monitor.store.schema import VECTORS
from jmlgdsl.page import Page

psycopg = pytest.importorskip("psycopg", reason="no psycopg: pip install 'psycopg[binary]'")

PASSWORD = "pl4nt-s3cret"


def binaries() -> str | None:
    """The folder of PostgreSQL's initdb and postgres: on PATH, or Debian's newest."""
    found = shutil.which("initdb")
    if found and shutil.which("postgres"):
        return os.path.dirname(os.path.realpath(found))
    folders = sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=lambda f: int(f.split("/")[-2]))
    return next((f for f in reversed(folders) if os.access(f"{f}/initdb", os.X_OK)), None)


class Server:
    """A fresh PostgreSQL cluster on 127.0.0.1 with a free port and no Unix socket, whose superuser
    `jmlgdsl` logs in with PASSWORD (scram-sha-256). PostgreSQL will not run as root: as root it runs
    as the user `postgres` (or `nobody`), who owns its folder."""

    def __init__(self, bin_folder: str):
        self.port = free_port()
        self.folder = tempfile.mkdtemp(prefix="jmlgdsl-postgres-")
        owner = None
        if os.geteuid() == 0:
            owner = next((pwd.getpwnam(n) for n in ("postgres", "nobody") if _user(n)), None)
            if owner is None:
                pytest.skip("running as root with neither a postgres nor a nobody user to run PostgreSQL as")
            os.chown(self.folder, owner.pw_uid, owner.pw_gid)
        as_owner = {} if owner is None else {"user": owner.pw_uid, "group": owner.pw_gid, "extra_groups": []}
        with open(f"{self.folder}/password", "w") as out:
            out.write(PASSWORD + "\n")
        if owner is not None:
            os.chown(f"{self.folder}/password", owner.pw_uid, owner.pw_gid)
        subprocess.run([f"{bin_folder}/initdb", "-D", f"{self.folder}/data", "-U", "jmlgdsl",
                        f"--pwfile={self.folder}/password", "--auth=scram-sha-256", "--no-sync", "-E", "UTF8",
                        "--locale=C"], check=True, capture_output=True, cwd=self.folder, timeout=120, **as_owner)
        self.log = open(f"{self.folder}/log", "w")
        self.process = subprocess.Popen([f"{bin_folder}/postgres", "-D", f"{self.folder}/data", "-h", "127.0.0.1",
                                         "-p", str(self.port), "-k", "", "-c", "fsync=off"],
                                        stdout=self.log, stderr=subprocess.STDOUT, cwd=self.folder, **as_owner)
        deadline = time.monotonic() + WAIT
        while True:
            try:
                self.connect("postgres").close()
                break
            except psycopg.OperationalError:
                if self.process.poll() is not None or time.monotonic() > deadline:
                    self.stop()
                    pytest.fail(f"PostgreSQL did not start: {open(f'{self.folder}/log').read()}")
                time.sleep(0.1)
        self.databases = 0

    def connect(self, database: str):
        return psycopg.connect(host="127.0.0.1", port=self.port, user="jmlgdsl", password=PASSWORD,
                               dbname=database, autocommit=True)

    def database(self) -> str:
        """The URL of a new, empty database."""
        self.databases += 1
        name = f"store{self.databases}"
        with self.connect("postgres") as db:
            db.execute(f"CREATE DATABASE {name}")
        return f"postgresql://jmlgdsl@127.0.0.1:{self.port}/{name}"

    def stop(self):
        self.process.send_signal(signal.SIGINT)  # a fast shutdown
        self.process.wait(WAIT)
        self.log.close()
        shutil.rmtree(self.folder, ignore_errors=True)


def _user(name: str) -> bool:
    try:
        pwd.getpwnam(name)
        return True
    except KeyError:
        return False


@pytest.fixture(scope="module")
def server():
    found = binaries()
    if found is None:
        pytest.skip("no PostgreSQL server (initdb, postgres) on PATH or in /usr/lib/postgresql/*/bin "
                    "(.ci/run installs it: apt-get install postgresql)")
    running = Server(found)
    yield running
    running.stop()


@pytest.fixture
def password(monkeypatch):
    """--store-password-env's variable, set."""
    monkeypatch.setenv("JMLGDSL_STORE_PASSWORD", PASSWORD)
    return ["--store-password-env", "JMLGDSL_STORE_PASSWORD"]


def table(*args, tmp_path, name="table.csv"):
    out = tmp_path / name
    assert main([*args, "-o", str(out)]) == 0
    return out.read_text()


def query(server, url, sql):
    """What SQL finds in the database of a store URL (None for a statement that finds nothing)."""
    with server.connect(url.rsplit("/", 1)[1]) as db:
        cursor = db.execute(sql)
        return cursor.fetchall() if cursor.description else None


def stored(server, url) -> int:
    """Rows with results committed in the store (0 before its tables exist)."""
    try:
        return query(server, url, "SELECT count(*) FROM result")[0][0]
    except psycopg.errors.UndefinedTable:
        return 0


@pytest.mark.parametrize("lag", [0, 3])
def test_export_equals_run(server, password, tmp_path, lag):
    url = server.database()
    options = ["--lag", str(lag), "--filter", "rbpf", "--seed", "3"]
    assert main(["monitor", SPEC, "--source", str(DATA), "--no-follow", "--store", url, *password, *options]) == 0
    exported = table("export", url, *password, "--samples", str(tmp_path / "rows.csv"), tmp_path=tmp_path)
    expected = table("run", SPEC, str(DATA), *options, tmp_path=tmp_path, name="run.csv")
    assert exported == expected and len(exported.splitlines()) == 1001 + (lag > 0)
    again = table("run", SPEC, str(tmp_path / "rows.csv"), *options, tmp_path=tmp_path, name="again.csv")
    assert again == expected
    # the columns are PostgreSQL's own types: a Grafana or SQL user reads numbers as numbers
    types = dict(query(server, url, "SELECT column_name, data_type FROM information_schema.columns "
                                    "WHERE table_name = 'sample'"))
    assert types["time"] == "double precision" and types["t"] == "bigint"
    assert query(server, url, "SELECT posterior[2] FROM result WHERE t = 1000")[0][0] > 0.9


def test_a_store_of_json_vectors_upgrades_in_place(server, password, tmp_path):
    url, first = server.database(), tmp_path / "first.csv"
    lines = DATA.read_text().splitlines(keepends=True)
    first.write_text("".join(lines[:501]))
    assert main(["monitor", SPEC, "--source", str(first), "--no-follow", "--store", url, *password]) == 0
    for table_name, columns in VECTORS.items():  # as schema 4 kept them: JSON text, null for NaN
        query(server, url, f"ALTER TABLE {table_name} " + ", ".join(
            f"ALTER COLUMN {c} TYPE TEXT USING replace(replace(array_to_json({c})::text, 'NaN', 'null'), ',', ', ')"
            for c in columns))
    query(server, url, "UPDATE meta SET value = '4' WHERE key = 'schema'")
    assert query(server, url, "SELECT posterior FROM result WHERE t = 500")[0][0].startswith("[")
    with open(first, "a") as out:
        out.writelines(lines[501:])
    assert main(["monitor", SPEC, "--source", str(first), "--no-follow", "--store", url, *password]) == 0
    assert query(server, url, "SELECT value FROM meta WHERE key = 'schema'") == [("5",)]
    assert {c: "ARRAY" for cs in VECTORS.values() for c in cs} == dict(query(
        server, url, "SELECT column_name, data_type FROM information_schema.columns WHERE column_name IN "
                     "('y', 'u', 'posterior', 'state_mean', 'y_pred', 'residual', 'y_sd', 'evidence')"))
    assert table("export", url, *password, tmp_path=tmp_path) == table("run", SPEC, str(DATA), tmp_path=tmp_path,
                                                                       name="run.csv")


def test_webhook_is_sent_every_transition_and_its_mark_kept(server, password, tmp_path):
    url, receiver = server.database(), Receiver()
    try:
        assert main(["monitor", SPEC, "--source", str(DATA), "--no-follow", "--store", url, *password,
                     "--notify", f"http://127.0.0.1:{receiver.port}/hook"]) == 0
    finally:
        receiver.close()
    assert receiver.transitions() == [(1, "raised"), (1, "cleared"), (2, "raised"), (2, "cleared"), (3, "raised")]
    assert query(server, url, "SELECT run, t, action FROM delivery") == [(1, 1000, 0)]


def test_a_user_who_may_only_read_exports_the_store(server, password, tmp_path, monkeypatch):
    url = server.database()
    assert main(["monitor", SPEC, "--source", str(DATA), "--no-follow", "--store", url, *password]) == 0
    query(server, url, "CREATE ROLE reader LOGIN PASSWORD 'r34der'; "
                       "GRANT SELECT ON ALL TABLES IN SCHEMA public TO reader")
    monkeypatch.setenv("JMLGDSL_STORE_PASSWORD", "r34der")
    reader = url.replace("jmlgdsl@", "reader@")
    assert table("export", reader, *password, tmp_path=tmp_path) == table("run", SPEC, str(DATA), tmp_path=tmp_path,
                                                                          name="run.csv")


def test_killed_and_restarted_loses_and_repeats_nothing(server, tmp_path):
    url = server.database()
    passfile = tmp_path / "pgpass"  # libpq's own password file: no password option at all
    passfile.write_text(f"127.0.0.1:{server.port}:*:jmlgdsl:{PASSWORD}\n")
    passfile.chmod(0o600)
    env = {**os.environ, "PGPASSFILE": str(passfile)}
    data = tmp_path / "growing.csv"
    command = [*jmlgdsl_command(), "monitor", SPEC, "--source", str(data), "--store", url, "--lag", "2"]
    err = killed_mid_file(command, data, lambda: stored(server, url), env)
    assert "resume: run 1 resumed after row" in err
    expected = table("run", SPEC, str(DATA), "--lag", "2", tmp_path=tmp_path, name="run.csv").splitlines(True)
    exported = subprocess.run([*jmlgdsl_command(), "export", url], capture_output=True, text=True, env=env,
                              timeout=WAIT)
    assert exported.returncode == 0, exported.stderr
    assert exported.stdout == "".join(expected[:-2])  # the last 2 rows wait for the 2 rows after them
    assert query(server, url, "SELECT count(*), min(t), max(t) FROM sample") == [(1000, 1, 1000)]
    assert dict(query(server, url, "SELECT kind, count(*) FROM event GROUP BY kind")) == {"start": 1, "resume": 1}


def test_the_page_reads_and_acts_on_the_store(server, password):
    url = server.database()
    assert main(["monitor", SPEC, "--source", str(DATA), "--no-follow", "--store", url, *password]) == 0
    page = Page(url, "127.0.0.1", 0, store_password=PASSWORD).start()
    try:
        def get(path):
            with urllib.request.urlopen(page.url + path, timeout=WAIT) as answer:
                return json.load(answer)

        run = get("api/run")
        assert run["modes"] == ["normal", "fan", "grill", "fan_grill"] and run["units"]["temp"] == "degC"
        assert get("api/rows")["t"] == list(range(701, 1001))
        assert get("api/rows?first=1&last=1000&limit=100")["t"] == list(range(1, 1001, 10))
        after = get("api/rows?after=995")
        assert after["t"] == [996, 997, 998, 999, 1000] and after["map_mode"][-1] == "fan"
        alarms = get("api/alarms")
        assert [(a["id"], a["mode"], a["state"]) for a in alarms] == [
            (3, "grill", "active, unacknowledged"), (2, "grill", "cleared, unacknowledged"),
            (1, "fan", "cleared, unacknowledged")]
        evidence = get("api/evidence?alarm=3")
        assert evidence["rows"] > 0 and evidence["outputs"][0]["name"] == "temp"
        request = urllib.request.Request(page.url + "api/alarms/3/acknowledge", data=b'{"who": "ann"}',
                                         headers={"Content-Type": "application/json"}, method="POST")
        with urllib.request.urlopen(request, timeout=WAIT) as answer:
            assert json.load(answer)[0]["state"] == "active, acknowledged"
        with urllib.request.urlopen(page.url + "api/stream?after=998", timeout=WAIT) as stream:
            events = [stream.readline().decode() for _ in range(7)]
        assert events[0] == "event: rows\n" and json.loads(events[2][6:])["t"] == [999, 1000]
        assert events[4] == "event: alarms\n" and json.loads(events[5][6:])[0]["acknowledged"]["who"] == "ann"
    finally:
        page.stop()
    assert query(server, url, "SELECT alarm, who, kind FROM action") == [(3, "ann", "acknowledge")]
    deadline = time.monotonic() + WAIT  # each request's connection is closed with it, the stream's once it ends
    while query(server, url, "SELECT count(*) FROM pg_stat_activity WHERE application_name = 'jmlgdsl'") != [(0,)]:
        assert time.monotonic() < deadline, "the page left connections to the store open"
        time.sleep(0.05)


def test_monitors_in_schemas_of_their_own_write_one_database_at_once(server, password, tmp_path):
    url = server.database()
    for line in ("line1", "line2"):
        query(server, url, f"CREATE SCHEMA {line}")
    env = {**os.environ, "JMLGDSL_STORE_PASSWORD": PASSWORD}
    monitors = [subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--source", str(DATA), "--no-follow",
                                  "--store", f"{url}?options=-csearch_path%3D{line}", *password],
                                 stderr=subprocess.PIPE, text=True, env=env) for line in ("line1", "line2")]
    for monitor in monitors:
        _, err = monitor.communicate(timeout=120)
        assert monitor.returncode == 0, err
    expected = table("run", SPEC, str(DATA), tmp_path=tmp_path, name="run.csv")
    for line in ("line1", "line2"):
        assert table("export", f"{url}?options=-csearch_path%3D{line}", *password, tmp_path=tmp_path) == expected
    assert query(server, url, "SELECT (SELECT count(*) FROM line1.result) + (SELECT count(*) FROM line2.result)") \
        == [(2000,)]


def test_a_wrong_password_is_refused_by_name_without_showing_it(server, monkeypatch, capsys, tmp_path):
    url = server.database()
    monkeypatch.setenv("JMLGDSL_STORE_PASSWORD", "not-the-password")
    monkeypatch.setenv("PGPASSFILE", str(tmp_path / "none"))  # no password from the user's own files
    arguments = ["--store", url, "--store-password-env", "JMLGDSL_STORE_PASSWORD"]
    assert main(["monitor", SPEC, "--source", str(DATA), "--no-follow", *arguments]) == 2
    err = capsys.readouterr().err
    assert f"error: cannot open the store {url}: " in err and 'password authentication failed for user "jmlgdsl"' in err
    assert "not-the-password" not in err
    assert main(["export", url]) == 2  # no password at all
    err = capsys.readouterr().err
    assert f"error: cannot open the store {url}: " in err and "--store-password-env or --store-password-file" in err
    secret_url = url.replace("jmlgdsl@", f"jmlgdsl:{PASSWORD}@")
    for location in (secret_url, f"{url}?password={PASSWORD}"):
        assert main(["export", location]) == 2
        err = capsys.readouterr().err
        assert "put no password in the store URL" in err and PASSWORD not in err
    with pytest.raises(Exception, match="an SQLite store takes no password"):
        Store(tmp_path / "dryer.db", password=PASSWORD)
    assert query(server, url, "SELECT count(*) FROM pg_tables WHERE schemaname = 'public'") == [(0,)]


def test_the_shards_of_a_fleet_on_ray_write_one_store(server, password, tmp_path):
    # four units in two Ray shards (two processes, each with its own connection) write one database
    pytest.importorskip("ray", reason="Ray is not installed (pip install '.[cluster]')")
    url = server.database()
    lines = DATA.read_text().splitlines(keepends=True)
    for k, unit in enumerate(("u1", "u2", "u3", "u4")):
        (tmp_path / f"{unit}.csv").write_text("".join([lines[0], *lines[1 + 50 * k:301 + 50 * k]]))
    assert main(["monitor", SPEC, "--units", "u1..u4", "--source", str(tmp_path / "{unit}.csv"), "--no-follow",
                 "--store", url, *password, "--cluster", "auto", "--shards", "2"]) == 0
    assert query(server, url, "SELECT unit, count(*) FROM result JOIN run ON run.id = result.run GROUP BY unit "
                              "ORDER BY unit") == [(unit, 300) for unit in ("u1", "u2", "u3", "u4")]
    for unit in ("u1", "u2", "u3", "u4"):
        assert (table("export", url, *password, "--unit", unit, tmp_path=tmp_path)
                == table("run", SPEC, str(tmp_path / f"{unit}.csv"), tmp_path=tmp_path, name="run.csv"))
