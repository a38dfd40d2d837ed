"""The options of a diagnosis on the command line (`run`, `monitor`, `bench`) beside the filter's
(`_filter`): the alarm rule, smoothing, the pre-filter, the evidence and the detect-then-name split,
and the one Options value (jmlgdsl.diagnosis.Options) built from them."""

from __future__ import annotations

from ._filter import check_particles
from ._types import names


def add_alarm_options(p):
    """The alarm rule's options: --healthy, --threshold, --persistence."""
    alarm = p.add_argument_group("alarm rule")
    alarm.add_argument("--healthy", metavar="MODE[,MODE...]",
                       help="the modes that raise no alarm (default: the first mode of the spec)")
    alarm.add_argument("--threshold", type=float, default=0.5,
                       help="alarm when P(not healthy) is above this (default 0.5)")
    alarm.add_argument("--persistence", type=int, default=1, metavar="K",
                       help="... at K consecutive steps; the alarm starts on the K-th (default 1)")


def add_smoothing_options(p):
    """A run's smoothing, pre-filter and evidence per sensor: --lag or --smooth, --prefilter, --explain."""
    when = p.add_mutually_exclusive_group()
    when.add_argument("--lag", type=int, metavar="L",
                      help="fixed-lag smoothing: report each row once L more rows have arrived, with "
                           "p(mode | data up to L rows later); fewer false alarms and errors around "
                           "switches, L samples late (also on a stream)")
    when.add_argument("--smooth", action="store_true",
                      help="off-line smoothing: every row with p(mode | all the data), written at the end")
    p.add_argument("--prefilter", metavar="ma:K",
                   help="causal moving average over the last K readings before filtering, for very noisy "
                        "signals (the filter then predicts the averaged signal)")
    p.add_argument("--explain", action="store_true",
                   help="the evidence per sensor: after the summary, for each alarm raised, the mode it points "
                        "at and the outputs that carry it (their share of the log-likelihood ratio of that mode "
                        "against the healthy ones, in nats; with several data files, under each unit's line); with -o "
                        "the table gains the columns evidence_mode and evidence_<output>")


def add_split_options(p):
    """A data file's detect-then-name split (jmlgdsl.diagnosis.alarms.DetectThenName): --detect, --name."""
    split = p.add_argument_group("detect, then name (one data file; the table holds the detector's columns)")
    split.add_argument("--detect", metavar="MODE,MODE[,...]", type=names,
                       help="the alarm from these modes alone (the healthy ones and a catch-all, e.g. "
                            "normal,anomaly). Default: when the bank has fault modes and a catch-all of a "
                            "healthy mode (that mode with every noise scaled up, 'like normal { noise scale S }', "
                            "as 'jmlgdsl learn' writes one), the healthy modes and the catch-all, without "
                            "--prefilter or --explain; otherwise the whole bank")
    split.add_argument("--name", metavar="MODE,MODE[,...]", type=names,
                       help="while the alarm is up, name each row by the most probable of these modes (the "
                            "fault modes, filtered on their own by Kalman filters that never mix, --filter mmae, "
                            "whatever --filter the detector has; default: the modes outside --detect). With the "
                            "true mode in the data the summary adds, per fault, the share of its rows named right "
                            "and the confusion among the faults")


def healthy_modes(args) -> list[str] | None:
    """The modes --healthy names (None: the spec's first mode)."""
    return [m.strip() for m in args.healthy.split(",")] if args.healthy else None


def diagnosis_options(args):
    """The diagnosis's Options from the flags of `run` or `monitor` (the monitor has no --smooth or
    --explain: it always explains)."""
    from ..diagnosis import Options
    from ..diagnosis.prefilter import parse

    healthy = healthy_modes(args)
    return Options(args.filter, args.particles, args.seed, args.resampling, args.ess_threshold,
                   None if getattr(args, "smooth", False) else args.lag or 0, parse(args.prefilter),
                   None if healthy is None else tuple(healthy), args.threshold, args.persistence,
                   getattr(args, "explain", False))


def model_and_options(args):
    """The spec's model (jmlgdsl.load) and the diagnosis's Options from the flags (`diagnosis_options`,
    refusing a bad pre-filter before the spec is read), --particles checked against the model."""
    import jmlgdsl

    options = diagnosis_options(args)
    model = jmlgdsl.load(args.spec)
    check_particles(args, model)
    return model, options
