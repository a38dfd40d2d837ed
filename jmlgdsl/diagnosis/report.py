"""The terminal report of a diagnosis: mode segments, the diagnosis error and the confusion matrix
where the data carry the true mode, the alarms and how well they detect, fit and speed; and the
evidence per sensor behind each alarm raised (`run --explain`)."""

from __future__ import annotations

import numpy as np

from ..names import plural


def smoothing(lag) -> str:
    """How the reported posteriors were conditioned, for the report's first line."""
    return "" if lag == 0 else ", smoothed off-line" if lag is None else f", smoothed with a lag of {plural(lag, 'step')}"


def report(diagnosis) -> str:
    """The whole report of a finished (or running) Diagnosis."""
    f, summary, model = diagnosis.filter, diagnosis.summary, diagnosis.model
    who = f"{f.algorithm}" + (f" with {f.particles} particles" if f.particles else "")
    lines = [f"{model.name}: {plural(summary.T, 'step')}, filter {who}" + smoothing(f.lag),
             "mode segments (most probable mode):"]
    for a, b, k, total in summary.segments:
        span = f"{a}" if a == b else f"{a}\u2013{b}"
        lines.append(f"  t {span}: {model.modes[k]} (p\u0304 {total / (b - a + 1):.2f})")
    if summary.more_segments:
        lines.append(f"  \u2026 {summary.more_segments} more segments (see the output CSV)")
    if summary.labelled:
        lines.append(f"diagnosis error: {summary.diagnosis_error:.2f} % ({summary.wrong} of {plural(summary.labelled, 'step')})")
        lines += confusion_report(model.modes, summary.confusion)
    lines += alarm_report(diagnosis)
    lines.append(f"log-likelihood: {summary.loglik:.2f}")
    lines.append(f"time per step: {1e3 * f.seconds / max(summary.T, 1):.3f} ms")
    return "\n".join(lines)


def confusion_report(modes, confusion) -> list[str]:
    """The confusion matrix as text: a row per true mode, a column per diagnosed mode (steps)."""
    width = max(6, *(len(m) for m in modes), len(str(int(confusion.max()))))
    lines = ["confusion (rows: true mode, columns: diagnosed mode, steps):",
             "  " + " " * width + " " + " ".join(f"{m:>{width}}" for m in modes)]
    lines += [f"  {m:>{width}} " + " ".join(f"{int(c):>{width}}" for c in row) for m, row in zip(modes, confusion)]
    return lines


def alarm_report(diagnosis) -> list[str]:
    """Lines on the alarms raised and, against the truth in the data, how well they detect."""
    rule, truth, lag = diagnosis.rule, diagnosis.truth, diagnosis.filter.lag
    lines = [f"alarms (healthy: {', '.join(rule.healthy)}; P(not healthy) > {rule.threshold:g} for "
             f"{plural(rule.persistence, 'step')}): {diagnosis.alarms.raised} raised"]
    if lag:
        lines[0] += f"; each is known {plural(lag, 'step')} after its row, later than the delays below"
    scores = None if truth is None else truth.scores()
    if scores is None:
        return lines
    o, e, nab = scores.outlier, scores.events, scores.nab
    lines += [
        f"detection: {e.detected} of {e.episodes} anomaly episodes ({e.detection_rate:.1f} %), delay mean "
        f"{e.mean_delay:.1f} s, median {e.median_delay:.1f} s; {plural(e.false_alarms, 'false alarm')} "
        f"({e.false_alarms_per_hour:.2f} per hour)",
        f"rows: F1 {o.f1:.3f}, false-alarm rate {o.far:.2f} %, missed-alarm rate {o.mar:.2f} %",
        f"NAB ({plural(nab.windows, 'change point')}): standard {nab.score('standard'):.2f}, low FP "
        f"{nab.score('lowfp'):.2f}, low FN {nab.score('lowfn'):.2f}"]
    return lines


def evidence_report(model, raised) -> list[str]:
    """Lines on the evidence behind each alarm of a `sinks.Raised` (of a Diagnosis that explains):
    its row, the mode it points at against the healthy mode that predicted the row best, the total
    log-likelihood ratio and the outputs that carry it, largest first, with their share of it."""
    lines = ["evidence behind the alarms raised (nats; the mode each points at against the healthy mode "
             "that predicted its row best):"]
    for done in raised.rows:
        at = f"t {done.step.t}" + ("" if done.row.time is None else f" (time {done.row.time:g})")
        e = done.evidence
        if e is None:
            lines.append(f"  {at}: no evidence (the filter holds no hypothesis in a healthy or in a non-healthy mode)")
            continue
        carriers = e.carriers()
        parts = [f"{model.outputs[i]} {v:.2f}" + (f" ({100 * v / e.total:.0f} %)" if e.total else "")
                 for i, v in carriers]
        others = int((~np.isnan(e.terms)).sum()) - len(carriers)
        if others:
            rest = e.total - sum(v for _, v in carriers)
            parts.append(f"{plural(others, 'other output')} {rest:.2f}")
        lines.append(f"  {at}: {model.modes[e.mode]} against {model.modes[e.healthy]}, {e.total:.2f}: "
                     + (", ".join(parts) if parts else "no output measured"))
    if raised.more:
        lines.append(f"  \u2026 {plural(raised.more, 'more alarm')} (see the evidence columns of the output CSV)")
    return lines


def naming_report(faults, counts) -> list[str]:
    """Lines on the naming of a detect-then-name run (`alarms.DetectThenName`) against the true modes:
    per fault, the share of its rows named right (all of them; and of those named while the alarm
    was up), then the confusion among the fault modes with a column for the rows not named."""
    lines = [f"naming: {counts.overall:.1f} % of the faulty rows named right "
             f"({int(counts.right.sum())} of {plural(int(counts.rows.sum()), 'row')})"]
    for name, n, right, share, alarmed in zip(faults, counts.rows, counts.right, counts.accuracy,
                                              counts.alarmed_accuracy):
        if n:
            lines.append(f"  {name}: {share:.1f} % ({right} of {n}), {alarmed:.1f} % of the rows named")
    columns = list(faults) + ["none"]
    width = max(6, *(len(m) for m in columns), len(str(int(counts.confusion.max()))))
    lines += ["naming confusion (rows: true fault, columns: named fault, none: no alarm; steps):",
              "  " + " " * width + " " + " ".join(f"{m:>{width}}" for m in columns)]
    lines += [f"  {m:>{width}} " + " ".join(f"{int(c):>{width}}" for c in row)
              for m, row, n in zip(faults, counts.confusion, counts.rows) if n]
    return lines
