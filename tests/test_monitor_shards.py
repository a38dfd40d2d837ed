"""A fleet's monitor spread over a local Ray cluster (`jmlgdsl monitor --units ... --cluster auto`),
every Ray server bound to 127.0.0.1 (checked against the machine's listening sockets): the units split into shards; a shard's process killed with
SIGKILL while its units' files grow is started again by Ray and resumes from its last commit, and
every unit's exported table equals the uninterrupted `jmlgdsl run` of its file, with no row lost or
stored twice. Also the refusals of the options that go with a cluster."""

import os
import re
import signal
import subprocess
import threading
import time

import pytest
from conftest import jmlgdsl_command
from monitor_servers import LINES, SPEC, WAIT, query, stop, until

from jmlgdsl.cli import main
from jmlgdsl.diagnosis.cluster import plain
from jmlgdsl.monitor.shards import ray_told, split

pytest.importorskip("ray", reason="Ray is not installed (pip install '.[cluster]')")

UNITS = ["p1", "p2", "p3", "p4"]


RAY_TEXT = ("A worker died or was killed while executing a task by an unexpected system "
            "error. To troubleshoot the problem, check the logs for the dead worker. Lease ID: 0100 Worker ID: b004 "
            "Node ID: 1079 Worker IP address: 127.0.0.1 Worker port: 38945 Worker PID: 13003 Worker exit type: "
            "SYSTEM_ERROR Worker exit detail: Worker unexpectedly exits with a connection error code 2. End of "
            "file. Some common causes include: (1) the process was killed by the OOM killer due to high memory\n"
            "usage, (2) ray stop --force was called, or (3) the worker crashed unexpectedly.")


def test_rays_messages_are_one_plain_line_in_the_monitors_words():
    """What Ray's raylet tells the driver (as print_to_stdstream is handed it), as the monitor logs it."""
    said = []
    report = ray_told(said.append)
    report(plain(RAY_TEXT))
    report(plain("Task Shard.run failed. There are infinite retries remaining, so the task "
                 "will be retried. Error: The actor is temporarily unavailable"))
    report(plain("\x1b[33mSomething\x1b[0m\n  else happened"))
    assert said == ["a shard's process (pid 13003) ended (SYSTEM_ERROR: Worker unexpectedly exits with a connection "
                    "error code 2); Ray starts it again, and its units resume from their last commit",
                    "ray: Something else happened"]


def test_units_are_split_into_contiguous_shards_of_nearly_equal_size():
    assert split(UNITS, 1) == [UNITS]
    assert split(UNITS, 3) == [["p1", "p2"], ["p3"], ["p4"]]
    assert split([f"u{i}" for i in range(10)], 4) == [["u0", "u1", "u2"], ["u3", "u4", "u5"], ["u6", "u7"],
                                                       ["u8", "u9"]]


def shard_processes(root: int) -> list[int]:
    """The processes below `root` (the monitor, whose local Ray's workers are its descendants) of Ray
    actors running a shard (Ray names them after the class and its method): another monitor's shards
    on the machine, such as another test run's, are not these."""
    parents, commands = {}, {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/stat", "rb") as stat:
                parents[int(pid)] = int(stat.read().rsplit(b")", 1)[1].split()[1])  # the field after the state
            with open(f"/proc/{pid}/cmdline", "rb") as cmdline:
                commands[int(pid)] = cmdline.read()
        except (OSError, IndexError, ValueError):
            continue

    def below(pid):
        while pid in parents and pid != root:
            pid = parents[pid]
        return pid == root

    return [pid for pid, command in commands.items() if command.startswith(b"ray::Shard") and below(pid)]


def listening() -> set[tuple[str, str]]:
    """(address, port) of every TCP socket listening on this machine, as /proc/net shows them (hex)."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as lines:
            for line in list(lines)[1:]:
                fields = line.split()
                if fields[3] == "0A":  # LISTEN
                    found.add(tuple(fields[1].split(":")))
    return found


LOOPBACK = {"0100007F", "00000000000000000000000001000000", "0000000000000000FFFF00000100007F"}


def rows_of(store, unit):
    return query(store, f"SELECT count(*) FROM result r JOIN run ON run.id = r.run WHERE run.unit = '{unit}'") or 0


def test_a_killed_shard_is_restarted_and_every_unit_table_equals_the_uninterrupted_run(tmp_path):
    files = {unit: tmp_path / f"{unit}.csv" for unit in UNITS}
    starts = {"p1": 0, "p2": 100, "p3": 200, "p4": 300}  # each unit its own stretch of the recording, 600 rows
    records = {unit: [LINES[0]] + LINES[1 + s:601 + s] for unit, s in starts.items()}
    for unit, path in files.items():
        path.write_text("".join(records[unit][:101]))
    store = str(tmp_path / "fleet.db")
    killed, done = threading.Event(), threading.Event()

    def grow():  # the plants' loggers: ten rows a unit every 10 ms, going on through the kill
        for start in range(101, 601, 10):
            if start == 301:
                killed.wait(WAIT)
            for unit, path in files.items():
                with open(path, "a") as out:
                    out.writelines(records[unit][start:start + 10])
            if done.wait(0.01):
                return

    command = [*jmlgdsl_command(), "monitor", SPEC, "--units", "p1..p4", "--source", str(tmp_path / "{unit}.csv"),
               "--store", store, "--cluster", "auto", "--shards", "2"]
    before = listening()
    monitor = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    writer = threading.Thread(target=grow)
    try:
        until(lambda: all(rows_of(store, u) >= 100 for u in UNITS), "every unit's first 100 rows", monitor)
        opened = listening() - before
        assert opened and {address for address, _ in opened} <= LOOPBACK, opened  # Ray's servers: 127.0.0.1 only
        writer.start()
        until(lambda: rows_of(store, "p1") >= 200, "unit p1's 200th row", monitor)
        shards = shard_processes(monitor.pid)
        assert len(shards) == 2
        victim = shards[0]
        os.kill(victim, signal.SIGKILL)
        assert rows_of(store, "p1") < 600  # mid-stream
        killed.set()
        until(lambda: all(rows_of(store, u) == 600 for u in UNITS), "every unit's 600 rows", monitor)
        after = shard_processes(monitor.pid)
        assert len(after) == 2 and victim not in after  # Ray started the killed shard again
        err = stop(monitor)
        writer.join(WAIT)
    finally:
        killed.set()
        done.set()
        if monitor.poll() is None:
            monitor.kill()
    assert "4 units in 2 shards on the Ray cluster auto" in err
    # the shard's death is one line of the monitor's own, without Ray's colour codes
    assert "\x1b" not in err and re.findall(r"^monitor: a shard's process.*$", err, re.M) == [
        f"monitor: a shard's process (pid {victim}) ended (SYSTEM_ERROR: Worker unexpectedly exits with a connection "
        "error code 2); Ray starts it again, and its units resume from their last commit"]
    # counted in the store: the killed shard's rows and events before its restart too
    assert (f"dryer: 2400 rows diagnosed in the runs of 4 units (1..4) of {store} by 2 shards (2400 in all); "
            "events: resume 2, start 4") in err
    for unit in UNITS:
        assert query(store, f"SELECT count(DISTINCT r.t) || ',' || min(r.t) || ',' || max(r.t) FROM result r "
                            f"JOIN run ON run.id = r.run WHERE run.unit = '{unit}'") == "600,1,600"
        assert main(["export", store, "--unit", unit, "-o", str(tmp_path / f"{unit}-store.csv")]) == 0
        assert main(["run", SPEC, str(files[unit]), "-o", str(tmp_path / f"{unit}-run.csv")]) == 0
        assert (tmp_path / f"{unit}-store.csv").read_text() == (tmp_path / f"{unit}-run.csv").read_text()
    # the killed shard's units were resumed, once each; the others ran on
    resumed = query(store, "SELECT group_concat(run.unit) FROM event JOIN run ON run.id = event.run "
                           "WHERE kind = 'resume'")
    assert resumed in ("p1,p2", "p2,p1", "p3,p4", "p4,p3")


@pytest.mark.parametrize("options, message", [
    (["--cluster", "auto"], "--cluster spreads the units of a fleet: give --units"),
    (["--shards", "2"], "--shards spreads the units of a fleet: give --units"),
    (["--units", "a,b", "--shards", "2"], "--shards needs --cluster"),
    (["--units", "a,b", "--cluster", "127.0.0.1:1"], "--cluster 127.0.0.1:1: nothing answers there"),
])
def test_the_options_of_a_cluster_are_refused_where_they_do_not_apply(tmp_path, capsys, options, message):
    source = str(tmp_path / ("{unit}.csv" if "--units" in options else "data.csv"))
    start = time.monotonic()
    assert main(["monitor", SPEC, "--source", source, "--store", str(tmp_path / "s.db"), *options]) == 2
    assert message in capsys.readouterr().err
    assert time.monotonic() - start < 10  # refused at once, not after Ray's own minutes of retrying


def test_a_shard_count_below_one_is_refused_as_it_is_read(tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        main(["monitor", SPEC, "--source", str(tmp_path / "{unit}.csv"), "--store", str(tmp_path / "s.db"),
              "--units", "a,b", "--cluster", "auto", "--shards", "0"])
    assert done.value.code == 2 and capsys.readouterr().err.endswith("argument --shards: must be at least 1, not 0\n")
    assert not (tmp_path / "s.db").exists()


def test_a_shard_never_makes_a_store_of_its_own(tmp_path):
    # on another machine of a cluster an SQLite path names no file: a shard would make a second store
    # there and diagnose into it; it refuses and says what a cluster of machines needs
    import jmlgdsl
    from jmlgdsl.monitor import MonitorOptions, StoreError
    from jmlgdsl.monitor.shards import Shard

    missing = tmp_path / "elsewhere.db"
    with pytest.raises(StoreError, match=r"is not on the machine of shard 1 .*share a PostgreSQL store"):
        Shard(jmlgdsl.load(SPEC), str(missing), None, None, MonitorOptions(), {}, ["p1"], 1,
              {"url": str(tmp_path / "{unit}.csv"), "follow": False})
    assert not missing.exists()


def processes() -> dict[int, tuple[int, str]]:
    """{pid: (parent pid, start time)} of every running process, as /proc shows them."""
    table = {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/stat") as stat:
                state, ppid, *fields = stat.read().rpartition(")")[2].split()
        except OSError:
            continue
        if state != "Z":
            table[int(pid)] = (int(ppid), fields[17])
    return table


def descendants(parent: int) -> dict[int, str]:
    """{pid: start time} of the running processes descended from `parent`."""
    table, found = processes(), {}
    for pid, (ppid, start) in table.items():
        while ppid not in (parent, 0, 1) and ppid in table:
            ppid = table[ppid][0]
        if ppid == parent:
            found[pid] = start
    return found


def test_a_monitor_killed_with_sigkill_leaves_no_process_of_its_local_ray(tmp_path):
    """Ray ends the processes it starts when the command dies, but its raylet's agents (dashboard,
    runtime env: about 160 MB) outlived a `kill -9` of the monitor; the reaper ends them."""
    for unit in ("p1", "p2"):
        (tmp_path / f"{unit}.csv").write_text("".join(LINES[:51]))
    store = str(tmp_path / "fleet.db")
    monitor = subprocess.Popen([*jmlgdsl_command(), "monitor", SPEC, "--units", "p1,p2", "--source",
                                str(tmp_path / "{unit}.csv"), "--store", store, "--cluster", "auto", "--shards", "1"],
                               stderr=subprocess.PIPE, text=True)
    try:
        until(lambda: rows_of(store, "p2") == 50, "unit p2's rows", monitor)
        started = descendants(monitor.pid)
        assert len(started) >= 3  # Ray's own processes (its servers, raylet and agents) and the shard, at least
    finally:
        monitor.kill()
        monitor.communicate()
    deadline = time.monotonic() + WAIT
    while left := {pid for pid, (_, start) in processes().items() if started.get(pid) == start}:
        assert time.monotonic() < deadline, f"processes of the killed monitor's Ray still run: {sorted(left)}"
        time.sleep(0.2)
