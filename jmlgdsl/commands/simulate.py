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


def requested_steps(args, rows) -> int | None:
    """The steps a command line asks for: --steps, else the end of --modes (read from its numbers,
    before a schedule is spelled out step by step), else the rows of --inputs."""
    import re

    if args.steps is not None:
        return args.steps
    if args.modes:
        return max((int(n) for n in re.findall(r"(\d{1,18})\s*:", args.modes)), default=None)
    return rows


def inputs(args, model):
    """The --inputs CSV's input rows (None without one), cut to --steps; a spec or model file given
    here, or a row count that does not match, is an error naming the file."""
    import warnings
    from pathlib import Path

    from ..data import DataWarning, read_csv
    from ..names import plural
    from ..errors import DataError

    if args.inputs is None:
        return None
    if Path(args.inputs).suffix.lower() in (".jmlg", ".json", ".npz", ".mat"):
        raise DataError(f"--inputs {args.inputs}: a spec or model file, not a CSV of inputs")
    u = read_csv(args.inputs, model, outputs=False).u
    if args.steps is not None and len(u) > args.steps:
        warnings.warn(f"{args.inputs}: {len(u)} rows; --steps {args.steps} uses the first {plural(args.steps, 'row')}",
                      DataWarning, stacklevel=2)
        return u[:args.steps]
    wanted = requested_steps(args, len(u))
    if len(u) != wanted:
        given = f"--steps {args.steps}" if args.steps is not None else f"the {plural(wanted, 'step')} of --modes"
        raise DataError(f"{args.inputs} has {plural(len(u), 'row')}, {'fewer' if len(u) < wanted else 'more'} "
                        f"than {given}")
    return u


def main(args) -> int:
    import jmlgdsl

    from ..data import write_columns
    from ..names import plural
    from ..output import check_count, check_file
    from ..simulation.linear import simulate, step_bytes

    check_file(args.output, inputs=[args.spec, args.inputs])
    if args.nonlinear:
        from ..simulation.nonlinear import load_nonlinear, simulate_nonlinear

        plant = load_nonlinear(args.spec)
        model = plant.model
    else:
        model = jmlgdsl.load(args.spec)
    steps = requested_steps(args, None)
    if steps is not None:
        check_count("--steps" if args.steps is not None else "--modes", steps, step_bytes(model))
    u = inputs(args, model)
    if args.nonlinear:
        sim = simulate_nonlinear(plant, args.steps, seed=args.seed, modes=args.modes, u=u)
    else:
        sim = simulate(model, args.steps, seed=args.seed, modes=args.modes, u=u)
    write_columns(args.output, sim.columns())
    if args.output != "-":  # as compile -o says what it wrote; standard output holds the data itself
        print(f"wrote {args.output} ({plural(len(sim.modes), 'row')}, {plural(model.K, 'mode')})")
    return 0
