"""`jmlgdsl compile SPEC -o FILE`: compile a spec to a model file (.json, .npz, or .mat for Matlab)."""

from __future__ import annotations


def register(sub):
    p = sub.add_parser(
        "compile", help="compile a spec to a .json, .npz or .mat model file",
        description="Compile a .jmlg spec to the stacked JMLG matrices and write them to FILE; the format "
                    "follows the suffix: .json (readable, exact), .npz (numpy), .mat (Matlab: per-mode "
                    "matrices indexed last, A(:,:,k)). Without -o, print the matrices.")
    p.add_argument("spec", metavar="SPEC", help="the .jmlg file")
    p.add_argument("-o", "--output", metavar="FILE", help="model file to write (.json, .npz or .mat)")
    p.add_argument("--show-jacobian", action="store_true",
                   help="for a nonlinear (ODE) plant, print the symbolic Jacobian the modes are built from")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from .. import load
    from ..names import plural
    from ..output import MODEL, check_file

    check_file(args.output, inputs=[args.spec], suffixes=MODEL)
    model = load(args.spec)
    if args.show_jacobian:
        from ..compile.ode import jacobian_report

        print(jacobian_report(args.spec))
    if args.output:
        model.save(args.output)
        print(f"wrote {args.output} ({plural(model.K, 'mode')}, nx={model.nx}, ny={model.ny}, nu={model.nu})")
    elif not args.show_jacobian:
        with np.printoptions(precision=6, suppress=True, linewidth=110):
            for k, mode in enumerate(model.modes):
                print(f"mode {mode}:")
                for key in ("A", "B", "C", "D", "F", "G", "f", "g", "mu0"):
                    arr = getattr(model, key)[k]
                    if arr.size:
                        print(f"  {key} =", str(arr).replace("\n", "\n" + " " * (len(key) + 5)))
            print(f"P =\n{model.P}\np0 = {model.p0}")
    return 0
