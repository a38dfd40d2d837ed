"""The options of a fleet's units and of where a command's work runs: --unit-specs (`run`, `monitor`)
and --cluster, the work spread over a Ray cluster (`run`, `bench`, `monitor`)."""

from __future__ import annotations


def add_unit_specs_option(p, when: str, spec: str, then: str):
    """--unit-specs DIR, its help saying `when` it applies, the `spec` path each unit's spec has in DIR
    and `then` what else holds."""
    p.add_argument("--unit-specs", metavar="DIR",
                   help=f"{when}: diagnose each unit with its own spec {spec} (the spec fitted to that unit: jmlgdsl "
                        f"fit SPEC units/*.csv -o DIR/), SPEC for a unit without one; {then}")


def add_cluster_option(p, what: str, where: str = "", then: str = ""):
    """--cluster auto|HOST:PORT, its help saying `what` the command does there, `where` what a cluster's
    machines need and `then` what else holds."""
    p.add_argument("--cluster", metavar="auto|HOST:PORT",
                   help=f"{what} (auto: a Ray on this machine for this command, reachable from 127.0.0.1 only; "
                        f"HOST:PORT: a cluster started with ray start --head{where}).{then} Needs pip install "
                        "'jmlgdsl[cluster]'")
