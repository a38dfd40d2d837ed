"""Ray, the engine that spreads jmlgdsl's work over processes and machines: the live shards of a
fleet's monitor (`jmlgdsl monitor --units ... --cluster ADDRESS`), the history of many files
(`jmlgdsl run SPEC *.csv -o OUT/ --cluster ADDRESS`) and the sweeps of `jmlgdsl bench`.

`--cluster auto` starts a Ray on this machine for the one command, every one of its servers bound
to 127.0.0.1 (reachable from this machine only) and stopped with the command; `--cluster
HOST:PORT` joins a cluster started with `ray start --head` (docs/fleet.md). Ray is an extra
(pip install 'jmlgdsl[cluster]'), imported only here and only when a cluster is asked for. Usage
statistics, which Ray would otherwise offer to send, stay off.

    >>> from jmlgdsl.cluster import connect
    >>> ray = connect("auto")             # doctest: +SKIP
    >>> ray.get(ray.remote(lambda xs: sum(xs)).remote([1, 2]))     # doctest: +SKIP
    3
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import socket
import sys

from .errors import JmlgError

LOCAL = "auto"
REACH = 5.0  # seconds a cluster's head has to answer
POLL = 0.2  # seconds between looks at a stop event while tasks run


class ClusterError(JmlgError):
    """No cluster: Ray missing, an address that answers nothing."""


def connect(address: str):
    """This process joined to the Ray cluster at `address` ('auto': a new local one on the loopback);
    returns the ray module. A process joins one cluster: a second call returns the same."""
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
    try:
        ray.init(address="local" if address == LOCAL else address, **options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise ClusterError(f"--cluster {address}: cannot join the Ray cluster ({exc})") from None
    return ray


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


@contextlib.contextmanager
def joined(address: str | None):
    """`connect(address)` for the block, then `disconnect()`; the ray module, or None (and nothing
    joined) for address None."""
    if address is None:
        yield None
        return
    ray = connect(address)
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
