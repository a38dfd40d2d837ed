"""Plants for the inference tests: the published dryer (method.md section 5) and small random models."""

import numpy as np

from jmlgdsl import Model

DRYER_SEQ1 = "1-70:normal,71-238:fan,239-365:grill,366-513:normal,514-705:grill,706-1000:fan"


def dryer() -> Model:
    """The industrial dryer of Table 5.3: four scalar modes driven by a constant input u = 1."""
    P = np.full((4, 4), 0.002) + np.eye(4) * (0.994 - 0.002)
    return Model.from_arrays(
        A=np.array([0.9676, 0.9609, 0.9762, 0.9701]).reshape(4, 1, 1), B=0.05, C=1.0, D=0.05,
        F=np.array([1.6321, 1.7247, 1.2981, 1.4042]).reshape(4, 1, 1), P=P,
        p0=[0.988, 0.004, 0.004, 0.004], mu0=np.array([[50.52], [44.16], [54.76], [46.99]]), Sigma0=0.0,
        modes=("normal", "fan", "grill", "fan_grill"), states=("x",), inputs=("one",),
        outputs=("temp",), input_defaults=[1.0], name="dryer")


def random_model(rng, K=3, nx=2, ny=2, nu=1, stay=0.8) -> Model:
    """A random stable JMLG model whose modes are far enough apart to be told from a few steps."""
    A = np.empty((K, nx, nx))
    for k in range(K):
        M = rng.normal(size=(nx, nx))
        A[k] = 0.9 * M / max(1.0, np.abs(np.linalg.eigvals(M)).max())
    P = np.full((K, K), (1 - stay) / (K - 1)) + np.eye(K) * (stay - (1 - stay) / (K - 1))
    return Model.from_arrays(
        A=A, B=0.3 * rng.normal(size=(K, nx, nx)), C=rng.normal(size=(K, ny, nx)),
        D=0.3 * np.eye(ny) + 0.05 * rng.normal(size=(K, ny, ny)), F=rng.normal(size=(K, nx, nu)),
        G=0.1 * rng.normal(size=(K, ny, nu)), f=rng.normal(size=(K, nx)), g=0.1 * rng.normal(size=(K, ny)),
        P=P, p0=np.full(K, 1.0 / K), mu0=rng.normal(size=(K, nx)), Sigma0=0.5 * np.eye(nx),
        input_defaults=np.ones(nu))
