"""Sealed state (jmlgdsl.sealed) gives back what it was given, exactly, with what was shared shared;
it refuses what it cannot hold when saving, and bytes that are damaged or name anything outside the
kinds it was told of when reading, without running any of it."""

import array
import collections
import math

import numpy as np
import pytest

from jmlgdsl.infer.engine import Gate
from jmlgdsl.infer.result import Step
from jmlgdsl.sealed import MAGIC, SealedError, header_of, seal, unseal


class Record:
    """A class of the caller's, with its fields."""


def test_what_is_sealed_comes_back_exactly_and_shared_as_it_was():
    generator = np.random.default_rng(5)
    generator.random(3)
    shared = np.arange(6, dtype=np.int64).reshape(2, 3)
    record = Record()
    record.items = [record]  # it holds itself
    step = Step(4, np.array([0.25, 0.75]), np.zeros(2), np.eye(2), np.ones(1), np.full(1, np.nan), -1.5, np.nan)
    value = {"n": 2 ** 80, "x": -0.0, "nan": math.nan, "inf": -math.inf, "s": "é\n\u0000", "none": None,
             (1, "key"): frozenset({1, 2}), "deque": collections.deque([1, 2], maxlen=3), "set": {3},
             "bytes": b"\x00\xff", "bytearray": bytearray(b"ab"), "doubles": array.array("d", [1.5, math.nan]),
             "slice": slice(1, None, 2), "scalars": (np.float64(0.1), np.int64(-3), np.bool_(True)),
             "arrays": (shared, shared, np.asfortranarray(np.arange(6.0).reshape(2, 3)), np.zeros((0, 4)),
                        np.array(1.5)),
             "generators": [generator, generator], "record": record, "gate": Gate.of([3.0]), "step": step}
    back = unseal(seal(value, {"what": "a test"}, (Record, Gate, Step)), (Record, Gate, Step))
    assert header_of(seal(value, {"what": "a test"}, (Record, Gate, Step))) == {"what": "a test"}
    assert back["n"] == 2 ** 80 and math.copysign(1, back["x"]) == -1 and math.isnan(back["nan"])
    assert back["inf"] == -math.inf and back["s"] == "é\n\u0000" and back["none"] is None
    assert back[(1, "key")] == frozenset({1, 2}) and back["deque"] == collections.deque([1, 2], maxlen=3)
    assert back["deque"].maxlen == 3 and back["set"] == {3} and back["bytes"] == b"\x00\xff"
    assert back["bytearray"] == bytearray(b"ab") and back["doubles"].typecode == "d"
    assert back["doubles"][0] == 1.5 and math.isnan(back["doubles"][1]) and back["slice"] == slice(1, None, 2)
    assert [type(v) for v in back["scalars"]] == [np.float64, np.int64, np.bool_] and back["scalars"][0] == 0.1
    a, b, fortran, empty, zero_d = back["arrays"]
    assert a is b and a.dtype == np.int64 and np.array_equal(a, shared) and a.flags.writeable
    assert np.array_equal(fortran, np.arange(6.0).reshape(2, 3)) and empty.shape == (0, 4) and zero_d.shape == ()
    first, second = back["generators"]
    assert first is second and first.random() == generator.random()
    assert type(back["record"]) is Record and back["record"].items[0] is back["record"]
    assert type(back["gate"]) is Gate and np.array_equal(back["gate"].limit, [3.0]) and back["gate"].bound == 9.0
    assert back["step"].t == 4 and back["step"].map_mode == 1
    assert np.array_equal(back["step"].residual, step.residual, equal_nan=True)


class Lazy:
    """A class that holds a field's value lazily: its property of the field's name makes it when read."""

    def __init__(self):
        vars(self)["made"] = None  # not made yet

    @property
    def made(self):
        held = vars(self)
        if held["made"] is None:
            held["made"] = np.arange(3.0)
        return held["made"]


def test_a_field_is_saved_as_its_attribute_reads():
    """A record's fields are read through its attributes, so one a property makes when read is saved
    made, and comes back as a plain field."""
    back = unseal(seal(Lazy(), {}, (Lazy,)), (Lazy,))
    assert type(back) is Lazy and np.array_equal(vars(back)["made"], [0.0, 1.0, 2.0])


@pytest.mark.parametrize("value", [lambda: None, np.array([object()]), Record(), open])
def test_what_it_cannot_hold_is_refused_when_saving(value):
    with pytest.raises(SealedError, match="^cannot save"):
        seal({"v": value}, {})


def test_damage_anywhere_is_refused_by_the_checksum():
    blob = seal({"a": np.arange(100.0), "b": "text"}, {"what": "a test"})
    for at in range(len(MAGIC), len(blob), 7):
        damaged = bytearray(blob)
        damaged[at] ^= 0x01
        with pytest.raises(SealedError, match="^damaged sealed state: its checksum does not match"):
            unseal(bytes(damaged))
    with pytest.raises(SealedError, match="^not jmlgdsl sealed state$"):
        unseal(b"\x80\x04pickle")
    with pytest.raises(SealedError, match="^damaged sealed state"):
        unseal(blob[:-1])  # cut short
