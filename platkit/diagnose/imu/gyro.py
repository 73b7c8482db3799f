"""The gyro between holds: the base model and the gyro effects, fitted on the segments.

    y_k = R_SP p_k + b0 + mean over segment k of sum_e gyro_bias_e(theta_e, t - t_c) + noise

The base model is an aligned sensor (R_SP = I) with a constant bias b0 (a constant gyro bias is
normal and is not a finding); each gyro effect (:class:`platkit.effects.ImuEffect` with
``sensor == 'gyro'``) adds its parameters through its own sensor model: R_SP from
``sensor_from_platform``, a bias from ``gyro_bias`` (averaged over the segment, five-point
Gauss-Legendre: exact for a bias polynomial up to degree 9). Weighted least squares, weight dt_k
(the noise of a mean rate falls as 1/sqrt(dt)).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from platkit.diagnose.imu.fitting import EffectFit, covariance, gauss_newton, numeric_columns, separability, split
from platkit.diagnose.imu.segments import Segments, blocks
from platkit.effects import ImuEffect, imu_sensor_model
from platkit.geometry import rotvec_from_matrix

_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)


@dataclass
class GyroFit(EffectFit):
    """The gyro model with ``effects`` on the segments: ``x`` = (b0 (3) rad/s, each effect's
    theta), ``resid`` (K, 3) rad/s on all segments, ``cv`` (K,) (rad/s)^2."""

    N_BASE: ClassVar[int] = 3
    model_cov: np.ndarray | None = None  # parameter covariance from the calibrated model's uncertainty (td)

    @property
    def b0(self) -> np.ndarray:
        return self.x[:3]

    @property
    def sensor_from_platform(self) -> np.ndarray:
        """(3, 3) R_SP of the fit."""
        return imu_sensor_model(list(zip(self.effects, self.thetas)))[0]


def gyro_model(seg: Segments, effects: tuple[ImuEffect, ...], x: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
    """(K, 3) rad/s: the mean rates the model with ``effects`` and parameters ``x`` predicts."""
    p = seg.p if p is None else p
    thetas = split(x, 3, [e.n_params for e in effects])
    R_sp = imu_sensor_model(list(zip(effects, thetas)))[0]
    out = p @ R_sp.T + x[:3]
    if effects:
        K = len(seg.dt)
        t = (seg.t_mid - seg.t_c)[:, None] + 0.5 * seg.dt[:, None] * _GL_X[None, :]  # (K, 5)
        for e, th in zip(effects, thetas):
            if type(e).gyro_bias is ImuEffect.gyro_bias:
                continue  # acts through another part of the sensor model
            b = np.asarray(e.gyro_bias(th, t.ravel()), float).reshape(K, len(_GL_X), 3)
            out = out + 0.5 * np.einsum("g,kgj->kj", _GL_W, b)
    return out


def fit_gyro(seg: Segments, effects: tuple[ImuEffect, ...], rows: np.ndarray | None = None,
             p: np.ndarray | None = None, separable: bool = False) -> GyroFit:
    """The gyro model with ``effects`` fitted on the segments ``rows`` (default all); residuals
    on all segments. ``p``: other model rates (K, 3) (default the segments' own); ``separable``:
    each effect's separability from the rest of the model too."""
    K = len(seg.dt)
    rows = np.ones(K, bool) if rows is None else rows
    n = 3 + sum(e.n_params for e in effects)
    w = np.sqrt(seg.dt / seg.dt.mean())
    eye = np.broadcast_to(np.eye(3), (K, 3, 3))

    def model(x):
        return gyro_model(seg, effects, x, p)

    def jacobian(x):
        if n == 3:
            return np.array(eye)
        return np.concatenate([eye, numeric_columns(model, x, range(3, n))], axis=2)

    x, Aw, _ = gauss_newton(seg.y, model, jacobian, np.zeros(n), w, rows)
    resid = seg.y - model(x)
    rss = float(np.sum((resid * w[:, None])[rows] ** 2))
    cov = covariance(Aw, rss, 3 * int(rows.sum()) - n)
    sep = {}
    i = 3
    for e in effects if separable else ():
        cols = np.zeros(n, bool)
        cols[i:i + e.n_params] = True
        sep[e.name] = separability(Aw, cols)
        i += e.n_params
    return GyroFit(tuple(effects), x, cov, resid, rss, n, sep)


def gyro_cv(seg: Segments, effects: tuple[ImuEffect, ...], block: int) -> np.ndarray:
    """(K,) held-out squared error per segment: fitted on the even blocks, scored on the odd, and
    the reverse."""
    even = blocks(len(seg.dt), block)
    out = np.empty(len(seg.dt))
    for train in (even, ~even):
        f = fit_gyro(seg, effects, train)
        out[~train] = np.sum(f.resid[~train] ** 2, axis=1)
    return out


def gyro_model_cov(seg: Segments, effects: tuple[ImuEffect, ...], p_draws: list[np.ndarray] | None) -> np.ndarray:
    """Covariance of the fit's parameters due to the calibrated model's own uncertainty: the
    spread of the refits with the model's rates from td drawn from its covariance."""
    n = 3 + sum(e.n_params for e in effects)
    if not p_draws or len(p_draws) < 2:
        return np.zeros((n, n))
    xs = np.array([fit_gyro(seg, effects, p=p).x for p in p_draws])
    return np.atleast_2d(np.cov(xs.T))


def full_fit(seg: Segments, effects: tuple[ImuEffect, ...], block: int, p_draws=None) -> GyroFit:
    """A fit with its held-out errors and (``p_draws``) its model covariance."""
    f = fit_gyro(seg, effects, separable=True)
    f.cv = gyro_cv(seg, effects, block)
    if p_draws is not None:
        f.model_cov = gyro_model_cov(seg, effects, p_draws)
    return f


def with_nuisances(effects: tuple[ImuEffect, ...], nuisances: tuple[ImuEffect, ...]) -> tuple[ImuEffect, ...]:
    """``effects`` and every nuisance effect not among them (fitted whether named or not)."""
    return tuple(effects) + tuple(e for e in nuisances if e not in effects)


def sensor_rotation(seg: Segments, effects: tuple[ImuEffect, ...], p: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The gyro's R_SP (3, 3) fitted with ``effects`` (the accepted ones and the nuisances) and
    the covariance (3, 3) rad^2 of a small rotation of it from the gyro noise."""
    f = fit_gyro(seg if p is None else replace(seg, p=p), effects)
    R = f.sensor_from_platform
    if f.n_params == 3:
        return R, np.zeros((3, 3))
    # how R_SP turns per parameter: G (3, n), then G C G^T

    def rot(x):
        return rotvec_from_matrix(imu_sensor_model(list(zip(f.effects, split(x, 3, [e.n_params for e in f.effects]))))[0] @ R.T)

    G = numeric_columns(rot, f.x, range(f.n_params))
    return R, G @ f.cov @ G.T


def noise_cov(f: GyroFit, name: str) -> np.ndarray:
    """(n, n) SI: an effect's parameter covariance from the noise and the calibrated model."""
    i = f.index(name)
    C = f.cov[i, i]
    if f.model_cov is not None:
        C = C + f.model_cov[i, i]
    return C
