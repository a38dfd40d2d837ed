"""The filter's options on the command line (`run`, `monitor`) and the check of --particles that
needs the model."""

from __future__ import annotations


def add_filter_options(p):
    """The filter's options: --filter, --particles, --seed, --resampling, --ess-threshold."""
    from ..infer import ALGORITHMS, DEFAULT_ALGORITHM
    from ..infer.resample import SCHEMES

    p.add_argument("--filter", default=DEFAULT_ALGORITHM, choices=list(ALGORITHMS),
                   help=f"filtering algorithm (default {DEFAULT_ALGORITHM})")
    p.add_argument("--particles", type=int, help="number of particles (default depends on the filter)")
    p.add_argument("--seed", type=int, help="random seed (the same seed gives the same output)")
    p.add_argument("--resampling", default="systematic", choices=list(SCHEMES), help="resampling scheme")
    p.add_argument("--ess-threshold", type=float, default=1.0,
                   help="resample when ESS < this fraction of the particles (1 = every step)")


def check_particles(args, model):
    """Refuse --particles for a filter without particles, or a count beyond this machine's memory."""
    from ..errors import JmlgError
    from ..infer import ALGORITHMS, particle_bytes
    from ..output import check_count

    if args.particles is None:
        return
    if not ALGORITHMS[args.filter].uses_particles:
        raise JmlgError(f"--particles: the {args.filter} filter uses no particles (the particle filters "
                        f"are {', '.join(n for n, a in ALGORITHMS.items() if a.uses_particles)})")
    check_count("--particles", args.particles, particle_bytes(model))
