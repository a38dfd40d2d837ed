"""Learned banks that switch: learn a three-mode bank from one PRBS experiment per mode, then
diagnose a switching sequence with the learned bank and with the true spec.

    python examples/learning/switching/study.py [--orders 2,3,auto] [--levels 0,45] [--exact]

The plant is `switching.jmlg` (two states, modes normal / slow / offset); `level` moves its operating
point. Each mode's experiment is a 315-sample PRBS (6 cells clocked every 5 samples, u = +-1); the
test sequence is 1,275 steps, normal -> slow -> normal -> offset -> normal, under a slower PRBS. The
learned bank takes its prior and transitions from the true spec, as `learn --template` does.
Prints a Markdown table of diagnosis errors (percent of steps whose MAP mode is wrong).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import jmlgdsl
from jmlgdsl.infer import filter as run_filter
from jmlgdsl.learn import bank
from jmlgdsl.learn.prbs import prbs

SPEC = Path(__file__).with_name("switching.jmlg")
SEQUENCE = "1-300:normal,301-550:slow,551-800:normal,801-1050:offset,1051-1275:normal"


def plant(level: float):
    """The switching plant with its operating level set."""
    text = SPEC.read_text().replace("level = 0", f"level = {level:g}")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "switching.jmlg"
        path.write_text(text)
        return jmlgdsl.load(path)


def experiments(model, seed=100):
    """One 315-sample PRBS experiment per mode, each with its own noise."""
    u = prbs(6, clock=5)[:, None]
    return {name: bank.Experiment(jmlgdsl.simulate(model, modes=[name] * len(u), u=u, seed=seed + k).y, u, name)
            for k, name in enumerate(model.modes)}


def learned_bank(model, exps, order):
    """The bank learned at `order` (N or "auto"), with the true spec's prior and transitions."""
    learned = bank.learn_modes(exps, order=order if order == "auto" else (order, order, 0))
    return bank.assemble(learned, P=model.P, p0=model.p0, operating_input=model.input_defaults,
                         name=model.name, dt=model.dt, inputs=model.inputs, outputs=model.outputs,
                         input_defaults=model.input_defaults), learned


def errors(model, sim, exact: bool) -> list[str]:
    """Diagnosis error (%) with fc-rbpf N=50 (seed 1), imm and, when asked, exact."""
    algorithms = [("fc-rbpf", 50), ("imm", None)] + ([("exact", None)] if exact else [])
    out = []
    for algorithm, n in algorithms:
        try:
            result = run_filter(model, sim.y, sim.u, algorithm=algorithm, particles=n, seed=1)
            out.append(f"{result.diagnosis_error(sim.modes):.2f} %")
        except jmlgdsl.JmlgError as exc:
            out.append(f"({type(exc).__name__})")
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--orders", default="2,3,auto")
    p.add_argument("--levels", default="0,45")
    p.add_argument("--exact", action="store_true", help="also run the exact filter")
    args = p.parse_args(argv)
    header = "| bank | level | states | fc-rbpf N=50 | imm |" + (" exact |" if args.exact else "")
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    for level in (float(v) for v in args.levels.split(",")):
        model = plant(level)
        u = prbs(7, clock=10, samples=1275)[:, None]
        sim = jmlgdsl.simulate(model, modes=SEQUENCE, u=u, seed=7)
        print(f"| true spec | {level:g} | {model.nx} | " + " | ".join(errors(model, sim, args.exact)) + " |")
        exps = experiments(model)
        for order in args.orders.split(","):
            learned, modes = learned_bank(model, exps, order if order == "auto" else int(order))
            orders = "/".join(str(lm.model.nx) for lm in modes)
            print(f"| learned, order {order} | {level:g} | {learned.nx} ({orders}) | "
                  + " | ".join(errors(learned, sim, args.exact)) + " |", flush=True)


if __name__ == "__main__":
    main()
