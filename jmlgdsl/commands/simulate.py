"""`jmlgdsl simulate SPEC`: draw a mode sequence, states and outputs; write the CSV that `run` reads."""

from __future__ import annotations


def register(subparsers):
    p = subparsers.add_parser(
        "simulate", help="simulate a plant and write its data as CSV",
        description="Simulate a plant: modes drawn from its Markov chain or following --modes, inputs "
                    "from their defaults or from a CSV; writes time, inputs, outputs, the true mode and "
                    "the true states (<state>_true), ready for 'jmlgdsl run'.")
    p.add_argument("spec", help="plant spec (.jmlg) or compiled model (.json/.npz)")
    p.add_argument("--steps", type=int, help="number of time steps (default: the end of --modes)")
    p.add_argument("--modes", metavar="SCHEDULE",
                   help='mode schedule, 1-based and inclusive, e.g. "1-70:normal,71-238:fan"')
    p.add_argument("--inputs", metavar="CSV", help="CSV with input columns (defaults fill the rest)")
    p.add_argument("--seed", type=int, help="random seed (the same seed gives the same file)")
    p.add_argument("-o", "--output", default="-", help="output CSV (default: standard output)")
    p.add_argument("--nonlinear", action="store_true",
                   help="integrate the plant's ODEs (a spec with an 'ode' block) instead of its linearised "
                        "modes, with the same modes and noise as the linear simulation of the same seed")
    p.set_defaults(func=main)


def main(args) -> int:
    import jmlgdsl

    from ..data import read_csv, write_columns
    from ..errors import DataError
    from ..simulate import simulate

    if args.nonlinear:
        from ..nonlinear import load_nonlinear, simulate_nonlinear

        plant = load_nonlinear(args.spec)
        model = plant.model
    else:
        model = jmlgdsl.load(args.spec)
    u = None if args.inputs is None else read_csv(args.inputs, model, outputs=False).u
    if args.steps is not None and args.steps < 1:
        raise DataError(f"--steps must be a positive number, got {args.steps}")
    if u is not None and args.steps is not None:
        if len(u) < args.steps:
            raise DataError(f"{args.inputs} has {len(u)} rows, fewer than --steps {args.steps}")
        u = u[:args.steps]
    if args.nonlinear:
        sim = simulate_nonlinear(plant, args.steps, seed=args.seed, modes=args.modes, u=u)
    else:
        sim = simulate(model, args.steps, seed=args.seed, modes=args.modes, u=u)
    write_columns(args.output, sim.columns())
    return 0
