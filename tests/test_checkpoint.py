"""A diagnosis saved mid-run and resumed in a fresh process continues bit for bit as the uninterrupted
one: every algorithm, with and without a lag, with the alarm rule's persistence, a pre-filter, truth
scoring and the evidence per sensor on. Saved state from another model or another version is refused
by name."""

import hashlib
import json
import os
import pickle
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, SOURCE, STARTUP_ENV

import jmlgdsl
from jmlgdsl.data import iter_rows, open_source
from jmlgdsl.diagnosis import CheckpointError, Diagnosis, Kept, Options
from jmlgdsl.diagnosis import pipeline
from jmlgdsl import sealed
from jmlgdsl.infer import ALGORITHMS

SPEC = ROOT / "specs" / "dryer.jmlg"
DATA = ROOT / "examples" / "dryer_seq1.csv"
# exact filtering keeps every mode history (4^t Gaussians): a few rows only
ROWS = {name: (8 if name == "exact" else 400) for name in ALGORITHMS}
CASES = [(name, lag) for name in ALGORITHMS for lag in (0, 3)]


def rows(count):
    model = jmlgdsl.load(SPEC)
    with open_source(DATA) as source:
        return [row for row, _ in zip(iter_rows(source, model, source.name), range(count))]


def diagnosis(model, name, lag, sinks):
    return Diagnosis(model, Options(algorithm=name, seed=7, lag=lag, prefilter=2, healthy=("normal",), threshold=0.6,
                                    persistence=2, explain=True), sinks=sinks)


def outcome(d, kept):
    """Everything a diagnosis concluded, as plain values to compare exactly."""
    steps = [k.step for k in kept.rows]
    return {"t": [s.t for s in steps], "posterior": np.array([s.mode_posterior for s in steps]),
            "mean": np.array([s.state_mean for s in steps]), "pred": np.array([s.y_pred for s in steps]),
            "loglik": np.array([s.loglik for s in steps]), "ess": np.array([s.ess for s in steps]),
            "alarm": [k.alarm for k in kept.rows],
            "evidence": np.array([[-1, -1, np.nan] if k.evidence is None else  # no particle in a healthy mode
                                  [k.evidence.mode, k.evidence.healthy, *k.evidence.terms] for k in kept.rows]),
            "summary": (d.summary.T, d.summary.wrong, d.summary.segments,
                                                             d.summary.confusion.tolist(), d.filter.loglik),
            "scores": d.truth.scores().summary(), "report": d.report().rsplit("\n", 1)[0]}  # less the time per step


RESUME = """
import pickle, sys
import jmlgdsl
from jmlgdsl.diagnosis import Diagnosis, Kept
cases = pickle.load(open(sys.argv[1], "rb"))
model = jmlgdsl.load(sys.argv[2])
done = {}
for key, (saved, earlier, rest) in cases.items():
    kept = Kept()
    kept.rows = earlier
    d = Diagnosis.resume(saved, model, sinks=[kept])
    for row in rest:
        d.feed(row)
    d.finish()
    done[key] = (d, kept)
pickle.dump({key: sys.modules["test_checkpoint"].outcome(*v) for key, v in done.items()}, open(sys.argv[3], "wb"))
"""


def test_a_resumed_diagnosis_continues_bit_for_bit_in_a_fresh_process(tmp_path):
    model = jmlgdsl.load(SPEC)
    whole, saved = {}, {}
    for name, lag in CASES:
        data = rows(ROWS[name])
        kept = Kept()
        d = diagnosis(model, name, lag, [kept])
        whole[name, lag] = outcome(d.run(data), kept)
        kept = Kept()
        d = diagnosis(model, name, lag, [kept])
        cut = len(data) // 2 + 1  # mid-run: with a lag, rows are held back in the window
        for row in data[:cut]:
            d.feed(row)
        saved[name, lag] = (d.checkpoint(), kept.rows, data[cut:])
    (tmp_path / "cases.pickle").write_bytes(pickle.dumps(saved))
    env = {**STARTUP_ENV, "PYTHONPATH": os.pathsep.join([str(ROOT / "tests")] + ([str(ROOT)] if SOURCE else []))}
    script = "import test_checkpoint\n" + RESUME
    subprocess.run([sys.executable, "-c", script, "cases.pickle", str(SPEC), "resumed.pickle"], cwd=tmp_path,
                   env=env, check=True, timeout=600)
    resumed = pickle.loads((tmp_path / "resumed.pickle").read_bytes())
    for case in CASES:
        a, b = whole[case], resumed[case]
        assert a.keys() == b.keys()
        for key in a:
            if isinstance(a[key], np.ndarray):
                assert np.array_equal(a[key], b[key], equal_nan=True), (case, key)
            else:
                assert a[key] == b[key] or (key == "scores" and _same_scores(a[key], b[key])), (case, key)
    assert any(max(w["alarm"]) for w in whole.values()) and any(w["summary"][1] for w in whole.values())


def _same_scores(a, b):
    return a.keys() == b.keys() and all(x == y or (x != x and y != y) for x, y in zip(a.values(), b.values()))


def test_a_checkpoint_is_refused_by_another_model_or_version():
    model = jmlgdsl.load(SPEC)
    d = diagnosis(model, "imm", 0, [])
    for row in rows(10):
        d.feed(row)
    saved = d.checkpoint()
    other = model.replace(outlier_gate=np.array([10.0]))
    with pytest.raises(CheckpointError, match=r"^the checkpoint was saved from another model \(plant 'dryer', "
                                              r"fingerprint [0-9a-f]{12}\) than this one \(plant 'dryer', "):
        Diagnosis.resume(saved, other)
    state = sealed.unseal(saved, pipeline.SAVED_KINDS, {"model": model})
    older = sealed.seal(state, {**sealed.header_of(saved), "version": "0.0.1"}, pipeline.SAVED_KINDS,
                           {"model": model})
    with pytest.raises(CheckpointError, match=rf"^the checkpoint was saved by jmlgdsl 0.0.1 \(format "
                                              rf"{pipeline.CHECKPOINT_FORMAT}\); this is "
                                              rf"jmlgdsl {jmlgdsl.__version__}, which cannot resume it"):
        Diagnosis.resume(older, model)
    with pytest.raises(CheckpointError, match="^not a jmlgdsl checkpoint$"):
        Diagnosis.resume(b"t,temp\n1,50\n", model)
    assert Diagnosis.resume(saved, jmlgdsl.load(SPEC)).summary.T == 10  # the same spec, loaded again


def test_a_pickled_checkpoint_of_an_earlier_version_is_refused_unread(tmp_path):
    """Format 2 checkpoints were pickles: one that a store's writer crafted to run code on resume
    is refused before a byte of the pickle is read."""
    model = jmlgdsl.load(SPEC)
    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    identity = {"format": 2, "version": jmlgdsl.__version__, "plant": model.name,
                "model": pipeline.fingerprint(model)}
    crafted = b"jmlgdsl-checkpoint\n" + json.dumps(identity).encode() + b"\n" + pickle.dumps({"x": Payload()})
    with pytest.raises(CheckpointError, match=r"^a checkpoint of an earlier jmlgdsl, saved as a Python pickle: "
                                              r"it is not read \(reading a pickle can run"):
        Diagnosis.resume(crafted, model)
    assert not marker.exists()


@pytest.mark.parametrize("node", [{"record": "subprocess.Popen", "fields": {}}, {"function": "os.system"},
                                  {"record": "jmlgdsl.infer.online.Filter", "fields": {"__class__": 1}},
                                  {"ndarray": ["|O", [1], 0]}, {"generator": "os.system", "state": None}])
def test_a_checkpoint_that_names_what_a_diagnosis_is_not_made_of_is_refused(node):
    """Saved state only ever makes the classes the diagnosis is made of: a checkpoint whose checksum
    matches but that names another class, a function, an object array or a dunder field is refused."""
    model = jmlgdsl.load(SPEC)
    identity = pipeline._identity(model)
    body = json.dumps(identity).encode() + b"\n" + json.dumps({"dict": [["filter", node]]}).encode() + b"\n"
    crafted = sealed.MAGIC + b"sha256 " + hashlib.sha256(body).hexdigest().encode() + b"\n" + body
    with pytest.raises(CheckpointError, match=r"^a jmlgdsl checkpoint that does not read back \(sealed state"):
        Diagnosis.resume(crafted, model)


def test_a_damaged_checkpoint_is_refused_by_its_checksum():
    model = jmlgdsl.load(SPEC)
    d = diagnosis(model, "la-rbpf", 3, [])
    for row in rows(20):
        d.feed(row)
    saved = d.checkpoint()
    rng = np.random.default_rng(3)
    for at in rng.choice(np.arange(len(sealed.MAGIC), len(saved)), 40, replace=False):
        damaged = bytearray(saved)
        damaged[at] ^= 1 << int(rng.integers(8))
        with pytest.raises(CheckpointError, match=r"^a damaged jmlgdsl checkpoint \(damaged sealed state: its "
                                                  r"checksum does not match its contents\)$"):
            Diagnosis.resume(bytes(damaged), model)
    resumed = Diagnosis.resume(saved, model)  # the same bytes undamaged
    assert resumed.filter.rng is resumed.filter.engine.rng  # one generator, shared as it was


def test_a_checkpoint_leaves_the_model_out():
    model = jmlgdsl.load(SPEC)
    d = diagnosis(model, "imm", 0, [])
    for row in rows(10):
        d.feed(row)
    assert b"jmlgdsl.model" in pickle.dumps(model)
    assert b"jmlgdsl.model" not in d.checkpoint()  # no Model in it: the model is given back, not saved
    assert pipeline.fingerprint(model) == pipeline.fingerprint(jmlgdsl.load(SPEC))


def test_an_unscored_diagnosis_keeps_a_state_of_constant_size():
    model = jmlgdsl.load(SPEC)
    data = rows(1000)
    scored, unscored = diagnosis(model, "imm", 0, []), Diagnosis(model, Options(
        algorithm="imm", seed=7, prefilter=2, healthy=("normal",), threshold=0.6, persistence=2), scored=False)
    sizes = []
    for i, row in enumerate(data):
        scored.feed(row)
        unscored.feed(row)
        if i in (99, 999):
            sizes.append((len(scored.checkpoint()), len(unscored.checkpoint())))
    (scored_100, unscored_100), (scored_1000, unscored_1000) = sizes
    assert scored_1000 - scored_100 > 8 * 900  # the alarm, truth and time of every row
    assert unscored_1000 - unscored_100 < pipeline.MAX_SEGMENTS * 64  # only the summary's few segments
    assert unscored.alarms.raised == scored.alarms.raised > 0
    assert unscored.report().splitlines()[:-1] == [line for line in scored.report().splitlines()[:-1]
                                                   if not line.startswith(("detection:", "rows:", "NAB"))]
