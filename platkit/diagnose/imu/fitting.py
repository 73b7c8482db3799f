"""Least squares shared by the gyro and accelerometer fits: Gauss-Newton on a model whose effect
parameters enter through the effects' own functions (central differences), the held-out split,
the F test and the separability of an effect's columns from the rest."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from scipy import linalg as sla
from scipy import stats

from platkit.diagnose.stats import column_basis

#: central-difference step for an effect's parameters (SI; the models are smooth in them)
STEP = 1e-6
#: Gauss-Newton stops when no parameter moves by more than this share of its value (or 1e-15)
TOLERANCE = 1e-9
MAX_ITERATIONS = 8


@dataclass
class EffectFit:
    """A sensor model fitted with ``effects``: ``x`` = (the ``N_BASE`` base parameters, each
    effect's theta in order), ``cov`` its covariance from the noise (``n_params``: the rank),
    ``resid`` on all rows, ``cv`` the held-out squared error per row (3 axes summed)."""

    N_BASE: ClassVar[int] = 0
    effects: tuple[Any, ...]
    x: np.ndarray
    cov: np.ndarray
    resid: np.ndarray
    rss: float
    n_params: int
    separability: dict[str, float]
    cv: np.ndarray | None = None

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def index(self, name: str) -> slice:
        """Where effect ``name``'s parameters sit in ``x``."""
        i = self.N_BASE
        for e in self.effects:
            if e.name == name:
                return slice(i, i + e.n_params)
            i += e.n_params
        raise KeyError(name)

    def theta(self, name: str) -> np.ndarray:
        return self.x[self.index(name)]

    @property
    def thetas(self) -> list[np.ndarray]:
        return split(self.x, self.N_BASE, [e.n_params for e in self.effects])

    @property
    def cv_rms(self) -> float:
        return float(np.sqrt(np.mean(self.cv) / 3.0))


def split(x: np.ndarray, n_base: int, sizes: list[int]) -> list[np.ndarray]:
    """The effects' parameter vectors out of ``x`` (base parameters first)."""
    out, i = [], n_base
    for n in sizes:
        out.append(x[i:i + n])
        i += n
    return out


def numeric_columns(model: Callable[[np.ndarray], np.ndarray], x: np.ndarray, cols: range,
                    at: np.ndarray | None = None) -> np.ndarray:
    """(..., len(cols)) forward-difference derivatives of ``model(x)`` (...) along ``cols`` of x
    (``at``: model(x) if already known). Exact for the parameters a model is linear in; for the
    others the step's error (about STEP relative) is far below what moves a fit."""
    m0 = model(x) if at is None else at
    out = []
    for j in cols:
        h = STEP * max(1.0, abs(x[j]))
        d = np.zeros_like(x)
        d[j] = h
        out.append((model(x + d) - m0) / h)
    return np.stack(out, axis=-1)


def gauss_newton(data: np.ndarray, model, jacobian, x0: np.ndarray, weights: np.ndarray, rows: np.ndarray,
                 rcond: float | None = None):
    """Weighted least squares of ``data`` (K, 3) by ``model(x)`` (K, 3) with ``jacobian(x)`` (K, 3, n)
    on the items ``rows`` (K,) bool, weight ``weights`` (K,) per item. Each step solves the model
    linearised at x for the whole vector (the minimum-norm solution where columns are
    dependent), so a model linear in x is solved in one step. Returns (x, Aw (3 rows, n), rank)."""
    x = np.asarray(x0, float).copy()
    for _ in range(MAX_ITERATIONS):
        A = jacobian(x)
        rhs = data - model(x) + np.einsum("kij,j->ki", A, x)
        Aw = (A * weights[:, None, None])[rows].reshape(-1, A.shape[2])
        bw = (rhs * weights[:, None])[rows].reshape(-1)
        x_new, _, rank, _ = np.linalg.lstsq(Aw, bw, rcond=rcond)
        done = np.all(np.abs(x_new - x) <= TOLERANCE * np.abs(x_new) + 1e-15)
        x = x_new
        if done:
            break
    return x, Aw, int(rank)


def covariance(Aw: np.ndarray, rss: float, dof: int) -> np.ndarray:
    return np.linalg.pinv(Aw.T @ Aw) * rss / max(dof, 1)


def separability(Aw: np.ndarray, cols: np.ndarray) -> float:
    """The smallest share of the signature of the columns ``cols`` (bool mask), in any direction,
    beyond what the other columns can mimic (0: absorbed, 1: orthogonal to them)."""
    J = Aw[:, cols]
    rest = Aw[:, ~cols]
    U = column_basis(rest) if rest.shape[1] else np.zeros((len(Aw), 0))
    Jp = J - U @ (U.T @ J)
    try:
        ev = sla.eigh(Jp.T @ Jp, J.T @ J, eigvals_only=True)
    except (np.linalg.LinAlgError, ValueError):
        return 0.0
    return float(np.sqrt(max(float(ev[0]), 0.0)))


def f_test(small, big, n_obs: int) -> tuple[float, float]:
    """F statistic and p-value of ``big`` against the nested ``small`` (``rss``, ``n_params``)."""
    k = max(big.n_params - small.n_params, 1)
    dof = n_obs - big.n_params
    F = ((small.rss - big.rss) / k) / max(big.rss / dof, 1e-300)
    return float(F), float(stats.f.sf(F, k, dof))
