"""Ray, the engine that spreads jmlgdsl's work over processes and machines: the live shards of a
fleet's monitor (`jmlgdsl monitor --units ... --cluster ADDRESS`), the history of many files
(`jmlgdsl run SPEC *.csv -o OUT/ --cluster ADDRESS`) and the sweeps of `jmlgdsl bench`.

`--cluster auto` starts a Ray on this machine for the one command, every one of its servers bound
to 127.0.0.1 (reachable from this machine only) and stopped with the command, however it ends: Ray
ends the processes it starts when the command dies, but not those its raylet starts (its dashboard
and runtime-env agents, about 160 MB, were left running after a `kill -9`), so a small reaper
process watches the command's processes and ends them once it is gone; `--cluster
HOST:PORT` joins a cluster started with `ray start --head` (docs/fleet.md). Ray is an extra
(pip install 'jmlgdsl[cluster]'), imported only here and only when a cluster is asked for. Usage
statistics, which Ray would otherwise offer to send, stay off.

    >>> from jmlgdsl.diagnosis.cluster import connect
    >>> ray = connect("auto")             # doctest: +SKIP
    >>> ray.get(ray.remote(lambda xs: sum(xs)).remote([1, 2]))     # doctest: +SKIP
    3
"""

from __future__ import annotations

import contextlib
import inspect
import ipaddress
import os
import re
import socket
import subprocess
import sys

from ..errors import JmlgError

LOCAL = "auto"
REACH = 5.0  # seconds a cluster's head has to answer
POLL = 0.2  # seconds between looks at a stop event while tasks run
COLOUR = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")  # a terminal's colour (or other CSI) code
_report = None  # where Ray's messages for this process go (connect's `report`)
_reaper = None  # the reaper of the local Ray this process started (a subprocess.Popen), while it runs


class ClusterError(JmlgError):
    """No cluster: Ray missing, an address that answers nothing."""


def connect(address: str, report=None):
    """This process joined to the Ray cluster at `address` ('auto': a new local one on the loopback);
    returns the ray module. A process joins one cluster: a second call returns the same. Ray's own
    messages for this process (a worker that died, a task tried again) go to `report(text)`, one line
    each without Ray's colour codes (default: standard error, after `ray: `)."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if "ray" not in sys.modules:  # Ray reads its authentication mode once, when it is imported
        os.environ.setdefault("RAY_AUTH_MODE", "token")  # as `ray start` sets up: the token in ~/.ray/auth_token
    if address != LOCAL:
        host = _reachable(address)
    loopback = address == LOCAL or ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
    if loopback:
        # Ray takes this machine's address from its outgoing interface, even for a cluster on the loopback,
        # unless told that it is not part of a cluster of machines; then its node address, and every
        # server's, is the loopback. The processes it starts read this from the environment; this one
        # read it when it imported Ray, which may have been before this call.
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    try:
        import ray
        from ray._private import ray_constants
    except ImportError:
        raise ClusterError("--cluster needs Ray: pip install 'jmlgdsl[cluster]'") from None
    if loopback:
        ray_constants.ENABLE_RAY_CLUSTER = False
    if ray.is_initialized():
        return ray
    options = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
    if address == LOCAL:
        _start_reaper()
    try:
        ray.init(address="local" if address == LOCAL else address, **options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        _stop_reaper()
        raise ClusterError(f"--cluster {address}: cannot join the Ray cluster ({exc})") from None
    if _reaper is not None:
        _reaper.stdin.write(b"started\n")  # the processes this one started since the reaper are Ray's
        _reaper.stdin.flush()
    _messages_to(report or (lambda text: print(f"ray: {text}", file=sys.stderr, flush=True)))
    return ray


def _messages_to(report):
    """Hand Ray's messages for the driver to `report`, each as one line of plain text. Ray prints them
    itself (in colour, over several lines, to standard output, whatever `log_to_driver` says) through
    its worker module's print_to_stdstream, with no switch to turn them off: that function is replaced
    for its raylet's messages (a Ray without it goes on printing them its own way)."""
    global _report
    from ray._private import worker

    _report = report
    printed = getattr(worker, "print_to_stdstream", None)
    if printed is None or printed.__module__ == __name__:  # none, or replaced already
        return

    def print_to_stdstream(data, ignore_prefix):
        if data.get("pid") != "raylet":
            return printed(data, ignore_prefix)
        for text in data.get("lines", ()):
            _report(plain(text))

    worker.print_to_stdstream = print_to_stdstream


def plain(text: str) -> str:
    """Text on one line without terminal colour codes (Ray's ESC [33m ...)."""
    return " ".join(COLOUR.sub("", text).split())


def _start_reaper():
    """Start the reaper of the local Ray's processes (on Linux: it reads /proc), which ends them once
    this process is gone, killed too. It runs in a session of its own (a Ctrl-C meant for the command
    does not reach it), learns which processes are Ray's from a line this process writes once Ray has
    started, and of this process's end from the end of the pipe it reads."""
    global _reaper
    if _reaper is None and os.path.isdir("/proc"):
        program = (f"# jmlgdsl: ends the local Ray's processes of process {os.getpid()} once it ends\n"
                   + inspect.getsource(_reap) + f"\n_reap({os.getpid()})\n")
        _reaper = subprocess.Popen([sys.executable, "-c", program], stdin=subprocess.PIPE,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def _stop_reaper():
    """End the reaper: what Ray left, if anything, is ended before this returns."""
    global _reaper
    if _reaper is not None:
        _reaper.stdin.close()
        _reaper.wait()
        _reaper = None


def _reap(parent: int):
    """The reaper's program, run on its own by `python -c` (so it imports nothing of jmlgdsl). Ray's
    processes are those `parent` started after the reaper and before it wrote a line to the reaper's
    standard input (Ray had started), and their descendants: every half second it notes them, each
    with its start time. When its standard input ends (`parent` is gone, however it ended) it ends
    those still running, SIGTERM and two seconds later SIGKILL. A process whose start time differs
    is another that took the number: it is left alone, as is any other process of `parent`'s."""
    import os
    import select
    import signal
    import sys
    import time

    def processes():
        """{pid: (parent pid, start time)} of every process /proc shows running (zombies left out)."""
        found = {}
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                with open(f"/proc/{pid}/stat") as stat:
                    state, ppid, *fields = stat.read().rpartition(")")[2].split()
            except (OSError, ValueError):
                continue
            if state != "Z":
                found[int(pid)] = (int(ppid), int(fields[17]))
        return found

    me = os.getpid()
    born = processes()[me][1]
    roots, seen = None, {}  # Ray's first processes; pid -> start time of every process of Ray's seen
    while True:
        if select.select([sys.stdin], [], [], 0.5)[0]:
            if not os.read(sys.stdin.fileno(), 1 << 12):
                break
            if roots is None:
                roots = {pid for pid, (ppid, start) in processes().items()
                         if ppid == parent and start >= born and pid != me}
        table = processes()
        for pid, (ppid, start) in table.items():
            ancestor = pid
            while ancestor not in (roots or ()) and ancestor in table and ancestor not in (parent, 0, 1):
                ancestor = table[ancestor][0]
            if ancestor in (roots or ()):
                seen[pid] = start
    for kill in (signal.SIGTERM, signal.SIGKILL):
        table = processes()
        left = [pid for pid, start in seen.items() if table.get(pid, (None, None))[1] == start]
        for pid in left:
            try:
                os.kill(pid, kill)
            except OSError:
                pass
        if not left:
            return
        time.sleep(2)


def _reachable(address: str) -> str:
    """The host of a cluster's HOST:PORT, once something answers there (Ray itself would wait minutes)."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ClusterError(f"--cluster {address}: give HOST:PORT of the cluster's head (ray start --head), or auto")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=REACH):
            return host.strip("[]")
    except OSError as exc:
        raise ClusterError(f"--cluster {address}: nothing answers there ({exc.strerror or exc}); is the cluster's "
                           "head started (ray start --head)?") from None


def disconnect():
    """Leave the cluster (and stop a local one this process started)."""
    ray = sys.modules.get("ray")
    if ray is not None and ray.is_initialized():
        ray.shutdown()
    _stop_reaper()


@contextlib.contextmanager
def joined(address: str | None, report=None):
    """`connect(address, report)` for the block, then `disconnect()`; the ray module, or None (and
    nothing joined) for address None."""
    if address is None:
        yield None
        return
    ray = connect(address, report)
    try:
        yield ray
    finally:
        disconnect()


def completed(ray, refs, stop=None):
    """(index, result) of each Ray task in `refs` as it finishes, until all have, or until `stop` (a
    threading.Event) is set. A task's jmlgdsl error is raised as itself, not wrapped in Ray's
    traceback (its message is the one a user gets without a cluster), and the tasks still running
    are cancelled."""
    index = {ref: i for i, ref in enumerate(refs)}
    waiting = list(refs)
    while waiting and not (stop is not None and stop.is_set()):
        ready, waiting = ray.wait(waiting, num_returns=1, timeout=None if stop is None else POLL)
        for ref in ready:
            try:
                yield index[ref], ray.get(ref)
            except ray.exceptions.RayTaskError as exc:
                for other in waiting:
                    ray.cancel(other)
                if isinstance(exc.cause, JmlgError):
                    raise exc.cause from None
                raise
