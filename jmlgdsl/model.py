"""The one model type everything downstream speaks: a compiled jump Markov linear Gaussian plant.

    z_t ~ P[z_{t-1}, :]                       z_0 ~ p0
    x_t = A[z] x_{t-1} + F[z] u_t + f[z] + B[z] w_t     x_0 | z_0 ~ N(mu0[z_0], Sigma0)
    y_t = C[z] x_t     + G[z] u_t + g[z] + D[z] v_t     w, v ~ N(0, I)

Per-mode arrays are stacked along a leading mode axis of length K.
"""

from __future__ import annotations

import dataclasses
import json
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from .data import with_defaults
from .errors import JmlgError
from .output import replacing

ARRAYS = ("A", "B", "C", "D", "F", "G", "f", "g", "P", "p0", "mu0", "Sigma0", "input_defaults")
NAMES = ("modes", "states", "inputs", "outputs")
# A reading farther than this many predicted standard deviations from what every mode hypothesis
# expects is a gross error (a glitch, a dropout, a unit slip), not information about the mode.
DEFAULT_GATE = 20.0


class ModelError(JmlgError, ValueError):
    """An inconsistent model built from arrays (wrong shapes, not a probability vector, ...)."""


@dataclass(frozen=True, eq=False)
class Model:
    """An immutable compiled plant: names, sample time and per-mode matrices stacked over modes."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    F: np.ndarray
    G: np.ndarray
    f: np.ndarray
    g: np.ndarray
    P: np.ndarray
    p0: np.ndarray
    mu0: np.ndarray
    Sigma0: np.ndarray
    input_defaults: np.ndarray
    modes: tuple[str, ...]
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    dt: float = 1.0
    name: str = "plant"
    descriptions: dict = field(default_factory=dict)  # mode name -> text
    engineering_units: dict = field(default_factory=dict)  # variable name -> its unit of measure, as the spec writes it
    # Per output: the gross-error gate in predicted standard deviations (inf: off); None = DEFAULT_GATE.
    outlier_gate: np.ndarray | None = None

    def __post_init__(self):
        for key in ARRAYS:
            arr = np.array(getattr(self, key), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, key, arr)
        for key in NAMES:
            object.__setattr__(self, key, tuple(str(n) for n in getattr(self, key)))
        gate = np.full(self.C.shape[1], DEFAULT_GATE) if self.outlier_gate is None else self.outlier_gate
        gate = np.array(gate, dtype=float).reshape(-1)
        gate.setflags(write=False)
        object.__setattr__(self, "outlier_gate", gate)
        object.__setattr__(self, "dt", float(self.dt))
        object.__setattr__(self, "descriptions", dict(self.descriptions))
        object.__setattr__(self, "engineering_units", dict(self.engineering_units))
        self._validate()

    # ----------------------------------------------------------------- sizes and derived arrays
    @property
    def K(self) -> int:
        return self.A.shape[0]

    @property
    def nx(self) -> int:
        return self.A.shape[1]

    @property
    def ny(self) -> int:
        return self.C.shape[1]

    @property
    def nu(self) -> int:
        return self.F.shape[2]

    @cached_property
    def Q(self) -> np.ndarray:
        """Process noise covariances B B' per mode, (K, nx, nx)."""
        return _readonly(self.B @ np.swapaxes(self.B, 1, 2))

    @cached_property
    def settles(self) -> bool:
        """Whether every mode settles to a steady state under constant inputs (every eigenvalue of
        every A inside the unit circle): an unstable or integrating mode can take its outputs anywhere."""
        return not (np.abs(np.linalg.eigvals(self.A)) >= 1.0).any()

    @cached_property
    def R(self) -> np.ndarray:
        """Measurement noise covariances D D' per mode, (K, ny, ny)."""
        return _readonly(self.D @ np.swapaxes(self.D, 1, 2))

    @cached_property
    def logP(self) -> np.ndarray:
        """Elementwise log of the transition matrix (-inf for impossible transitions)."""
        with np.errstate(divide="ignore"):
            return _readonly(np.log(self.P))

    @cached_property
    def output_states(self) -> slice | None:
        """The states the outputs read, as a slice, when every mode's C is the same run of identity
        rows (y_i = x_(start+i) + ...; learned banks are), else None: the Kalman kernel then takes
        views of covariances instead of multiplying by C."""
        if self.ny == 0:
            return None
        start = int(self.C[0, 0].argmax())
        picks = slice(start, start + self.ny)
        if start + self.ny <= self.nx and (self.C == np.eye(self.nx)[picks]).all():
            return picks
        return None

    def mode_index(self, name: str) -> int:
        """Index of a mode by name; ModelError naming the known modes otherwise."""
        try:
            return self.modes.index(name)
        except ValueError:
            raise ModelError(f"unknown mode {name!r}; modes are {', '.join(self.modes)}") from None

    def resolve_inputs(self, u, T: int) -> np.ndarray:
        """Inputs as a (T, nu) array: `u` as given, or the spec's constant defaults when u is None."""
        if u is None:
            if np.isnan(self.input_defaults).any():
                missing = [n for n, d in zip(self.inputs, self.input_defaults) if np.isnan(d)]
                raise ModelError(f"inputs without a default must be given: {', '.join(missing)}")
            return with_defaults(np.full((T, self.nu), np.nan), self.input_defaults)
        u = np.asarray(u, dtype=float)
        if u.size != T * self.nu:
            raise ModelError(f"inputs must be {T} steps x {self.nu} ({', '.join(self.inputs) or 'no inputs'}), "
                             f"got shape {u.shape}")
        return u.reshape(T, self.nu)

    def replace(self, **changes) -> "Model":
        """A copy with some fields changed (the model itself is immutable); a change in the number of
        outputs takes the default outlier gate unless it gives one."""
        if "C" in changes and "outlier_gate" not in changes and np.shape(changes["C"])[1] != self.ny:
            changes["outlier_gate"] = None
        return dataclasses.replace(self, **changes)

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_arrays(cls, A, B, C, D, P, p0, mu0, Sigma0, F=None, G=None, f=None, g=None,
                    modes=None, states=None, inputs=None, outputs=None, input_defaults=None,
                    dt=1.0, name="plant", **extra) -> "Model":
        """Build a model from matrices; a 2-D A (one mode) and scalars are promoted to stacks."""
        A = np.asarray(A, dtype=float)
        if A.ndim == 2:
            A = A[None]
        if A.ndim != 3:
            raise ModelError(f"A must be (K, nx, nx) or (nx, nx), got shape {A.shape}")
        K, nx = A.shape[0], A.shape[1]
        C = _stack(C, K, "C")
        ny = C.shape[1]
        B = _stack(B, K, "B")
        D = _stack(D, K, "D")
        F = None if F is None else _stack(F, K, "F")
        G = None if G is None else _stack(G, K, "G")
        nu = F.shape[2] if F is not None else G.shape[2] if G is not None else 0
        F = np.zeros((K, nx, nu)) if F is None else F
        G = np.zeros((K, ny, nu)) if G is None else G
        f = np.zeros((K, nx)) if f is None else np.broadcast_to(np.asarray(f, float), (K, nx))
        g = np.zeros((K, ny)) if g is None else np.broadcast_to(np.asarray(g, float), (K, ny))
        mu0 = np.broadcast_to(np.asarray(mu0, float), (K, nx))
        Sigma0 = np.asarray(Sigma0, float)
        if Sigma0.ndim == 0:
            Sigma0 = Sigma0 * np.eye(nx)
        return cls(
            A=A, B=B, C=C, D=D, F=F, G=G, f=f, g=g, P=np.atleast_2d(np.asarray(P, float)),
            p0=np.atleast_1d(np.asarray(p0, float)), mu0=mu0, Sigma0=Sigma0,
            input_defaults=np.full(nu, np.nan) if input_defaults is None else input_defaults,
            modes=modes or tuple(f"mode{k + 1}" for k in range(K)),
            states=states or tuple(f"x{i + 1}" for i in range(nx)),
            inputs=inputs or tuple(f"u{i + 1}" for i in range(nu)),
            outputs=outputs or tuple(f"y{i + 1}" for i in range(ny)),
            dt=dt, name=name, **extra)

    def _validate(self):
        K, nx, ny, nu = self.K, self.nx, self.ny, self.nu
        if self.A.ndim != 3 or self.A.shape[2] != nx:
            raise ModelError(f"A must be (K, nx, nx), got {self.A.shape}")
        expect = {
            "B": (K, nx, None), "C": (K, ny, nx), "D": (K, ny, None), "F": (K, nx, nu),
            "G": (K, ny, nu), "f": (K, nx), "g": (K, ny), "P": (K, K), "p0": (K,),
            "mu0": (K, nx), "Sigma0": (nx, nx), "input_defaults": (nu,),
        }
        for key, shape in expect.items():
            got = getattr(self, key).shape
            if len(got) != len(shape) or any(s is not None and s != g for s, g in zip(shape, got)):
                want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
                raise ModelError(f"{key} must have shape {want} for K={K}, nx={nx}, ny={ny}, nu={nu}; got {got}")
        for key, n in (("modes", K), ("states", nx), ("inputs", nu), ("outputs", ny)):
            if len(getattr(self, key)) != n:
                raise ModelError(f"{len(getattr(self, key))} {key} named for {n}")
        for key in ARRAYS:
            if key != "input_defaults" and not np.isfinite(getattr(self, key)).all():
                raise ModelError(f"{key} has entries that are not finite numbers")
        if (self.P < 0).any() or not np.allclose(self.P.sum(axis=1), 1.0, atol=1e-9):
            raise ModelError("every row of P must be a probability vector")
        if (self.p0 < 0).any() or not np.isclose(self.p0.sum(), 1.0, atol=1e-9):
            raise ModelError("p0 must be a probability vector")
        if nx and (not np.allclose(self.Sigma0, self.Sigma0.T) or np.linalg.eigvalsh(self.Sigma0).min() < 0):
            raise ModelError("Sigma0 must be symmetric positive semi-definite")
        if self.outlier_gate.shape != (ny,) or not (self.outlier_gate > 0).all():
            raise ModelError(f"outlier_gate must hold {ny} positive numbers of standard deviations (inf: off)")
        R = self.D @ np.swapaxes(self.D, 1, 2)
        if ny and np.linalg.eigvalsh(R).min() <= 0:
            raise ModelError("measurement noise D D' must be positive definite in every mode")

    # ----------------------------------------------------------------- files
    def to_dict(self) -> dict:
        """Plain JSON-able dictionary holding every field (arrays as nested lists)."""
        out = {"format": "jmlgdsl-model", "version": 1, "name": self.name, "dt": self.dt,
               "descriptions": self.descriptions, "units": self.engineering_units}
        out.update({k: list(getattr(self, k)) for k in NAMES})
        for k in ARRAYS:
            arr = getattr(self, k)
            out[k] = {"shape": list(arr.shape), "data": [None if np.isnan(v) else float(v) for v in arr.ravel()]}
        out["outlier_gate"] = [None if np.isinf(v) else float(v) for v in self.outlier_gate]  # None: off
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "Model":
        if d.get("format") != "jmlgdsl-model":
            raise ModelError("not a jmlgdsl model file (missing format: jmlgdsl-model)")
        kw = {k: np.array([np.nan if v is None else v for v in d[k]["data"]], float).reshape(d[k]["shape"])
              for k in ARRAYS}
        kw.update({k: tuple(d.get(k, ())) for k in NAMES})
        gate = d.get("outlier_gate")
        gate = None if gate is None else [np.inf if v is None else v for v in gate]
        return cls(dt=d["dt"], name=d["name"], descriptions=d.get("descriptions", {}),
                   engineering_units=d.get("units", {}), outlier_gate=gate, **kw)

    def save(self, path) -> Path:
        """Write to .json (readable, exact: floats round-trip), .npz, or .mat (export for Matlab);
        a file that cannot be written is a ModelError."""
        path = Path(path)
        try:
            with replacing(path) as temporary:  # whole or not at all; the same suffix, so the same format
                self._write(temporary)
        except OSError as exc:
            raise ModelError(f"cannot write model file {path}: {exc.strerror or exc}") from None
        return path

    def _write(self, path: Path):
        """Write the file `save` promises, in the format its suffix names."""
        suffix = path.suffix.lower()
        if suffix == ".json":
            path.write_text(json.dumps(self.to_dict(), indent=1))
        elif suffix == ".npz":
            meta = {k: v for k, v in self.to_dict().items() if k not in ARRAYS + ("outlier_gate",)}
            with open(path, "wb") as fh:
                np.savez(fh, meta=json.dumps(meta), outlier_gate=self.outlier_gate,
                         **{k: getattr(self, k) for k in ARRAYS})
        elif suffix == ".mat":
            from scipy.io import savemat
            mdict = {k: getattr(self, k) for k in ARRAYS}
            # Matlab users index modes last: A(:,:,k).
            for k in ("A", "B", "C", "D", "F", "G"):
                mdict[k] = np.moveaxis(mdict[k], 0, -1)
            mdict.update({k: np.array(getattr(self, k), dtype=object) for k in NAMES})
            mdict.update(dt=self.dt, name=self.name)
            savemat(path, mdict)
        else:
            raise ModelError(f"unknown model file type {suffix!r}: use .json, .npz or .mat")

    @classmethod
    def read(cls, path) -> "Model":
        """Read a model written by `save` (.json or .npz); a missing, foreign or damaged file is a
        ModelError naming the file."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".json", ".npz"):
            raise ModelError(f"cannot read model files of type {suffix!r}: use .json or .npz")
        try:
            return cls._read_json(path) if suffix == ".json" else cls._read_npz(path)
        except ModelError as exc:
            raise ModelError(f"{path}: {exc}") from None
        except OSError as exc:
            raise ModelError(f"cannot read model file {path}: {exc.strerror or exc}") from None
        except KeyError as exc:
            raise ModelError(f"{path}: not a complete jmlgdsl model file: {exc} is missing") from None
        except (ValueError, TypeError, EOFError, zipfile.BadZipFile) as exc:
            raise ModelError(f"{path}: not a readable jmlgdsl model file ({type(exc).__name__}: {exc})") from None

    @classmethod
    def _read_json(cls, path: Path) -> "Model":
        """The model in a .json file written by `save`."""
        return cls.from_dict(json.loads(path.read_text()))

    @classmethod
    def _read_npz(cls, path: Path) -> "Model":
        """The model in a .npz file written by `save`: arrays as they are, names and sizes in `meta`."""
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("format") != "jmlgdsl-model":
                raise ModelError("not a jmlgdsl model file")
            fields = {k: tuple(v) if k in NAMES else v for k, v in meta.items() if k not in ("format", "version")}
            fields["engineering_units"] = fields.pop("units", {})  # the files' name for them (to_dict)
            gate = z["outlier_gate"] if "outlier_gate" in z.files else None
            return cls(**{k: z[k] for k in ARRAYS}, **fields, outlier_gate=gate)

    def __repr__(self):
        return (f"Model({self.name!r}, K={self.K} modes {list(self.modes)}, nx={self.nx}, ny={self.ny}, "
                f"nu={self.nu}, dt={self.dt:g} s)")


def _stack(M, K, name):
    M = np.asarray(M, dtype=float)
    if M.ndim == 0:
        M = M.reshape(1, 1)
    if M.ndim == 2:
        M = np.broadcast_to(M, (K,) + M.shape)
    if M.ndim != 3 or M.shape[0] != K:
        raise ModelError(f"{name} must be (K, rows, cols) or (rows, cols); got shape {M.shape} for K={K}")
    return M


def _readonly(a):
    a.setflags(write=False)
    return a
