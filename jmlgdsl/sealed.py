"""Sealed state: the bytes a checkpoint is kept in, data only and with a checksum, so that reading
them back can never run code (a store that others can write, or a copied file, is no way into the
process that resumes).

What is saved is a tree of numbers, strings, None, lists, tuples, dicts, sets, deques, slices,
bytes, numeric numpy arrays and scalars, numpy random generators (their bit generator's state) and
records of the classes and functions the caller names in `kinds`: a record is its class's name and
its fields (each as its attribute reads, so a class may make a field's value only when it is read),
put back with `object.__new__` and the fields set, so no constructor, `__setstate__` or
import of a name the bytes give is ever run. Objects met twice are saved once and come back shared
(a filter's generator, its resampler's and its engine's are one). Objects named in `given` (the
model a diagnosis runs on) are left out and given back by the reader.

The layout, format 1:

    jmlgdsl-sealed 1\\n
    sha256 HEX\\n                  the SHA-256 of everything after this line
    HEADER\\n                      the caller's own JSON object (what the state is, who saved it)
    TREE\\n                        the tree as JSON; arrays, bytes as [dtype, shape, offset] into DATA
    DATA                          the arrays' and bytes' contents, little-endian, one after the other

`unseal` checks the checksum before it reads anything else: damaged bytes are refused, not used.
"""

from __future__ import annotations

import array
import collections
import hashlib
import json
import math
import types

import numpy as np

from .errors import JmlgError

MAGIC = b"jmlgdsl-sealed 1\n"
DTYPE_KINDS = "biufc"  # numpy arrays of booleans and numbers only
GENERATORS = {name: getattr(np.random, name) for name in ("PCG64", "PCG64DXSM", "Philox", "SFC64", "MT19937")}
ARRAY_CODES = "bBhHiIlLqQfd"  # array.array type codes of numbers
# the mutable objects a tree may hold besides records: each is saved once, however often it is met
MUTABLE = (list, dict, set, collections.deque, bytearray, array.array, np.ndarray, np.random.Generator)


class SealedError(JmlgError):
    """Bytes that are not sealed state this version can read: not such bytes, damaged (the checksum
    does not match), or holding a kind of object the reader was not told of."""


def seal(value, header: dict, kinds=(), given=None) -> bytes:
    """`value` as sealed state, with `header` (JSON) to tell what it is; `kinds` are the classes and
    functions its records may be of, `given` {name: object} the objects left out by name."""
    writer = _Writer({f"{k.__module__}.{k.__qualname__}": k for k in kinds}, given or {})
    tree = json.dumps(writer.node(value), separators=(",", ":")).encode()
    body = json.dumps(header, separators=(",", ":")).encode() + b"\n" + tree + b"\n" + b"".join(writer.data)
    return MAGIC + b"sha256 " + hashlib.sha256(body).hexdigest().encode() + b"\n" + body


def is_sealed(blob: bytes) -> bool:
    """Whether bytes claim to be sealed state (they begin as it does)."""
    return bytes(blob[:len(MAGIC)]) == MAGIC


def header_of(blob: bytes) -> dict:
    """The header of sealed state whose checksum matches; a SealedError otherwise."""
    return _verified(blob)[0]


def unseal(blob: bytes, kinds=(), given=None):
    """The value `seal` saved, its checksum verified first; `kinds` and `given` as `seal` had them.
    A SealedError for bytes that are damaged, or hold a kind of object not in `kinds`."""
    _, tree, data = _verified(blob)
    reader = _Reader({f"{k.__module__}.{k.__qualname__}": k for k in kinds}, given or {}, data)
    try:
        return reader.value(tree)
    except SealedError:
        raise
    except (TypeError, ValueError, KeyError, IndexError, AttributeError, OverflowError, RecursionError) as exc:
        raise SealedError(f"sealed state that does not read back ({type(exc).__name__}: {exc})") from None


def _verified(blob: bytes):
    """(header, tree, data) of sealed state whose checksum matches."""
    blob = bytes(blob)
    if not is_sealed(blob):
        raise SealedError("not jmlgdsl sealed state")
    line, _, body = blob[len(MAGIC):].partition(b"\n")
    if line != b"sha256 " + hashlib.sha256(body).hexdigest().encode():
        raise SealedError("damaged sealed state: its checksum does not match its contents")
    head, _, rest = body.partition(b"\n")
    tree, _, data = rest.partition(b"\n")
    try:
        found = json.loads(head)
        tree = json.loads(tree)
    except (ValueError, RecursionError):
        raise SealedError("sealed state whose checksum matches but whose contents are not readable") from None
    if not isinstance(found, dict):
        raise SealedError("sealed state whose header is not a JSON object")
    return found, tree, data


class _Writer:
    """The tree of a value, every object it holds numbered in the order met (the reader numbers them
    in the same order), an object met again a reference to its number."""

    def __init__(self, kinds: dict, given: dict):
        self.kinds = {kind: name for name, kind in kinds.items()}
        self.given = {id(obj): name for name, obj in given.items()}
        self.seen = {}  # id -> (number, object): the object is held, so its id is not reused meanwhile
        self.data, self.size = [], 0

    def node(self, value):
        if value is None or isinstance(value, (bool, str)):
            return value
        if type(value) is int:
            return value
        if type(value) is float:
            return value if math.isfinite(value) else {"float": repr(value)}
        if id(value) in self.given:
            return {"given": self.given[id(value)]}
        if id(value) in self.seen:
            return {"ref": self.seen[id(value)][0]}
        kind = type(value)
        if kind is tuple:
            return {"tuple": [self.node(v) for v in value]}
        if isinstance(value, np.generic) and value.dtype.kind in DTYPE_KINDS:
            return {"scalar": self._bytes(np.asarray(value))}
        if kind is frozenset:
            return {"frozenset": [self.node(v) for v in value]}
        if kind is slice:
            return {"slice": [self.node(value.start), self.node(value.stop), self.node(value.step)]}
        if kind is bytes:
            return {"bytes": self._bytes(np.frombuffer(value, np.uint8))}
        if kind in self.kinds and isinstance(value, tuple):  # a named tuple
            return {"record": self.kinds[kind], "items": [self.node(v) for v in value]}
        if isinstance(value, types.FunctionType) and value in self.kinds:
            return {"function": self.kinds[value]}
        if kind not in MUTABLE and kind not in self.kinds:
            raise SealedError(f"cannot save an object of type {kind.__module__}.{kind.__qualname__}")
        number = len(self.seen)
        self.seen[id(value)] = (number, value)
        if kind is list:
            return {"list": [self.node(v) for v in value]}
        if kind is dict:
            return {"dict": [[self.node(k), self.node(v)] for k, v in value.items()]}
        if kind is set:
            return {"set": [self.node(v) for v in value]}
        if kind is collections.deque:
            return {"deque": [self.node(v) for v in value], "maxlen": value.maxlen}
        if kind is bytearray:
            return {"bytearray": self._bytes(np.frombuffer(bytes(value), np.uint8))}
        if kind is array.array:
            return {"array.array": value.typecode, "of": self._bytes(np.asarray(value))}
        if kind is np.ndarray:
            if value.dtype.kind not in DTYPE_KINDS:
                raise SealedError(f"cannot save a numpy array of {value.dtype}")
            return {"ndarray": self._bytes(value)}
        if kind is np.random.Generator:
            bits = value.bit_generator
            if type(bits).__name__ not in GENERATORS:
                raise SealedError(f"cannot save a generator of {type(bits).__name__}")
            return {"generator": type(bits).__name__, "state": self.node(bits.state)}
        slots = [s for c in kind.__mro__ for s in getattr(c, "__slots__", ()) if hasattr(value, s)]
        # each field as its attribute reads (a class may hold a field's value lazily behind a property)
        fields = {k: getattr(value, k) for k in list(vars(value))} if hasattr(value, "__dict__") else {}
        fields.update((s, getattr(value, s)) for s in slots)
        return {"record": self.kinds[kind], "fields": {k: self.node(v) for k, v in fields.items()}}

    def _bytes(self, values: np.ndarray) -> list:
        """[dtype, shape, offset] of an array whose contents go to the data, little-endian."""
        dtype = values.dtype.newbyteorder("<")
        raw = values.astype(dtype, copy=False).tobytes()  # in C order, whatever the array's
        at, self.size = self.size, self.size + len(raw)
        self.data.append(raw)
        return [dtype.str, list(values.shape), at]


class _Reader:
    """The value of a tree, every object numbered as the writer met them."""

    def __init__(self, kinds: dict, given: dict, data: bytes):
        self.kinds, self.given, self.data = kinds, given, data
        self.seen = []

    def value(self, node):
        if node is None or isinstance(node, (bool, int, float, str)):
            return node
        if not isinstance(node, dict) or not node:
            raise SealedError(f"sealed state with an unknown node {str(node)[:60]}")
        tag, body = next(iter(node.items()))
        if tag == "float":
            found = float(body)
            if math.isfinite(found):
                raise SealedError(f"sealed state with a float node of {body!r}")
            return found
        if tag == "given":
            if body not in self.given:
                raise SealedError(f"sealed state that refers to {body!r}, which this reader does not give")
            return self.given[body]
        if tag == "ref":
            return self.seen[body]
        if tag == "tuple":
            return tuple(self.value(v) for v in body)
        if tag == "frozenset":
            return frozenset(self.value(v) for v in body)
        if tag == "slice":
            return slice(*(self.value(v) for v in body))
        if tag == "scalar":
            return self._array(body)[()]
        if tag == "bytes":
            return self._array(body).tobytes()
        if tag == "function":
            return self._kind(body)
        if tag == "record" and "items" in node:
            return self._kind(body)._make(self.value(v) for v in node["items"])
        return self._object(tag, body, node)

    def _object(self, tag, body, node):
        """A mutable object: numbered before what it holds is read (so it may hold itself)."""
        number = len(self.seen)
        self.seen.append(None)
        if tag == "list":
            found = self.seen[number] = []
            found.extend(self.value(v) for v in body)
        elif tag == "dict":
            found = self.seen[number] = {}
            for k, v in body:
                key = self.value(k)
                found[key] = self.value(v)
        elif tag == "set":
            found = self.seen[number] = set()
            found.update(self.value(v) for v in body)
        elif tag == "deque":
            found = self.seen[number] = collections.deque(maxlen=node["maxlen"])
            found.extend(self.value(v) for v in body)
        elif tag == "bytearray":
            found = self.seen[number] = bytearray(self._array(body).tobytes())
        elif tag == "array.array":
            if body not in ARRAY_CODES:
                raise SealedError(f"sealed state with an array of type code {body!r}")
            found = self.seen[number] = array.array(body, self._array(node["of"]).astype(body).tobytes())
        elif tag == "ndarray":
            found = self.seen[number] = self._array(body)
        elif tag == "generator":
            if body not in GENERATORS:
                raise SealedError(f"sealed state with a generator of {body!r}")
            found = self.seen[number] = np.random.Generator(GENERATORS[body]())
            found.bit_generator.state = self.value(node["state"])
        elif tag == "record":
            kind = self._kind(body)
            if not isinstance(kind, type):
                raise SealedError(f"sealed state with a record of {body!r}, which is not a class")
            found = self.seen[number] = object.__new__(kind)
            slots = {s for c in kind.__mro__ for s in getattr(c, "__slots__", ())}
            for name, v in node["fields"].items():
                if not isinstance(name, str) or not name.isidentifier() or name.startswith("__"):
                    raise SealedError(f"sealed state with a field named {str(name)[:60]!r}")
                if name in slots:
                    object.__setattr__(found, name, self.value(v))
                else:
                    vars(found)[name] = self.value(v)
        else:
            raise SealedError(f"sealed state with an unknown node {tag!r}")
        return found

    def _kind(self, name):
        if name not in self.kinds:
            raise SealedError(f"sealed state that holds a {name!r}, which this version does not read")
        return self.kinds[name]

    def _array(self, body) -> np.ndarray:
        """An array of the data: [dtype, shape, offset], a copy it owns."""
        dtype, shape, at = body
        dtype = np.dtype(dtype)
        if dtype.kind not in DTYPE_KINDS or dtype.byteorder == ">" or not all(
                isinstance(n, int) and n >= 0 for n in shape) or not isinstance(at, int) or at < 0:
            raise SealedError(f"sealed state with an array of {dtype} {shape}")
        size = dtype.itemsize * math.prod(shape)
        if at + size > len(self.data):
            raise SealedError("sealed state whose arrays run past its end")
        return np.frombuffer(self.data, dtype, math.prod(shape), at).reshape(shape).copy()
