"""The accelerometer at the holds: gravity turned by the model's orientation, and the
accelerometer effects.

While the platform holds command k the accelerometer reads gravity alone:

    f_k = diag(g_s) R_SP R_k^T R_LB^T (0, 0, 1) + b_a + sum_e accelerometer_bias_e(theta_e, t_k - t_c) + noise

R_k the model's orientation of the held command (base from platform), R_SP the sensor's rotation
against the model's platform frame as the gyro sees it (its fit with the nuisance effects, named
or not: the gyro sees R_SP whatever the base's tilt), g_s (3) the gravity each axis reads (local
gravity times the axis's scale) and b_a (3) a constant bias: the base model, always fitted, never
a finding. R_LB (the level frame from the model's base) comes from the accelerometer effects'
``level_from_base`` (e.g. a tilted base: gravity in the model's base frame is R_LB^T (0, 0, -g),
the conventions of :mod:`platkit.inertial.simulate`).

A tilt turns gravity alike at every pose, so most of what it does is a constant the bias takes;
only the platform's own rotation tells them apart. The *separability* of an effect is the
smallest share of its signature on the holds that the base model cannot mimic; an effect with a
``min_separability`` is not tested below it.

An effect's covariance has four sources: ``noise``; ``model`` (refits with td drawn from the
calibration's covariance: other model orientations and R_SP); ``sensor`` (the gyro noise in
R_SP); ``frame`` (the model's frames against the real ones, the effect's ``frame_covariance``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from platkit.diagnose.imu.fitting import EffectFit, covariance, gauss_newton, numeric_columns, separability, split
from platkit.diagnose.imu.gyro import sensor_rotation
from platkit.diagnose.imu.segments import Holds, Segments, blocks, model_rates
from platkit.effects import ImuEffect, imu_sensor_model
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, rotvec_from_matrix

G_STANDARD = 9.80665


@dataclass
class AccFit(EffectFit):
    """The accelerometer at the holds: ``x`` = (gravity per axis (3) m/s^2, bias (3) m/s^2, each
    effect's theta), ``resid`` (H, 3) m/s^2 on all holds, ``cv`` (H,) (m/s^2)^2,
    ``sensor_rotation`` (3) rad the R_SP used (rotation vector)."""

    N_BASE: ClassVar[int] = 6
    sensor_rotation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    effect_cov: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # name -> source -> (n, n) SI

    @property
    def scale(self) -> np.ndarray:
        return self.x[:3]

    @property
    def bias(self) -> np.ndarray:
        return self.x[3:6]

    def total_cov(self, name: str) -> np.ndarray:
        """(n, n) SI: an effect's covariance from every source."""
        n = self.index(name).stop - self.index(name).start
        return sum(self.effect_cov.get(name, {}).values(), np.zeros((n, n)))


def up_in_sensor(R: np.ndarray, R_sp: np.ndarray, R_lb: np.ndarray | None = None) -> np.ndarray:
    """(H, 3): the up direction in sensor axes, R_SP R_k^T R_LB^T e_z, for the model's
    orientations R (H, 3, 3) base from platform, the sensor's rotation R_SP (3, 3) and the level
    frame from the base R_LB (3, 3) (None: level): a still platform's accelerometer reads g times
    this, plus its bias."""
    v = np.eye(3)[2] if R_lb is None else np.asarray(R_lb, float)[2]  # R_LB^T e_z
    return np.einsum("kji,j->ki", R, v) @ R_sp.T


def acc_model(holds: Holds, t_c: float, R_sp: np.ndarray, effects: tuple[ImuEffect, ...], x: np.ndarray,
              R: np.ndarray | None = None) -> np.ndarray:
    """(H, 3) m/s^2: the specific force the model predicts at the holds."""
    R = holds.R if R is None else R
    thetas = split(x, 6, [e.n_params for e in effects])
    R_lb = imu_sensor_model(list(zip(effects, thetas)))[1]
    out = up_in_sensor(R, R_sp, R_lb) * x[:3] + x[3:6]
    for e, th in zip(effects, thetas):
        if type(e).accelerometer_bias is not ImuEffect.accelerometer_bias:
            out = out + np.asarray(e.accelerometer_bias(th, holds.t - t_c), float)
    return out


def fit_acc(holds: Holds, t_c: float, R_sp: np.ndarray, effects: tuple[ImuEffect, ...], rows: np.ndarray | None = None,
            R: np.ndarray | None = None, separable: bool = False) -> AccFit:
    """Weighted least squares (weight: the samples averaged) of the accelerometer model on the
    holds ``rows`` (default all); residuals on all holds. ``R``: other model orientations of the
    holds (H, 3, 3) (default the holds' own); ``separable``: each effect's separability from the
    rest of the model too."""
    H = len(holds.rows)
    rows = np.ones(H, bool) if rows is None else rows
    Rh = holds.R if R is None else R
    n = 6 + sum(e.n_params for e in effects)
    wt = np.sqrt(holds.n / holds.n.mean())
    eye = np.broadcast_to(np.eye(3), (H, 3, 3))

    def model(x):
        return acc_model(holds, t_c, R_sp, effects, x, Rh)

    def jacobian(x):
        thetas = split(x, 6, [e.n_params for e in effects])
        u = up_in_sensor(Rh, R_sp, imu_sensor_model(list(zip(effects, thetas)))[1])
        cols = [u[:, :, None] * np.eye(3)[None], eye]
        if n > 6:
            cols.append(numeric_columns(model, x, range(6, n)))
        return np.concatenate(cols, axis=2)

    x0 = np.r_[np.full(3, G_STANDARD), np.zeros(n - 3)]
    x, Aw, rank = gauss_newton(holds.f, model, jacobian, x0, wt, rows, rcond=1e-10)
    resid = holds.f - model(x)
    rss = float(np.sum((resid * wt[:, None])[rows] ** 2))
    cov = covariance(Aw, rss, 3 * int(rows.sum()) - rank)
    sep = {}
    i = 6
    for e in effects if separable else ():
        cols = np.zeros(n, bool)
        cols[i:i + e.n_params] = True
        sep[e.name] = separability(Aw, cols)
        i += e.n_params
    return AccFit(tuple(effects), x, cov, resid, rss, rank, sep, sensor_rotation=rotvec_from_matrix(R_sp))


def acc_cv(holds: Holds, t_c: float, R_sp: np.ndarray, effects: tuple[ImuEffect, ...], block: int) -> np.ndarray:
    """(H,) held-out squared error per hold (even blocks fit the odd ones and the reverse)."""
    even = blocks(len(holds.rows), block)
    out = np.empty(len(holds.rows))
    for train in (even, ~even):
        f = fit_acc(holds, t_c, R_sp, effects, train)
        out[~train] = np.sum(f.resid[~train] ** 2, axis=1)
    return out


def acc_state(seg: Segments, gyro_effects: tuple[ImuEffect, ...], effects: tuple[ImuEffect, ...], block: int,
              q_draws: list[np.ndarray] | None = None, frame_base: np.ndarray | None = None,
              frame_platform: np.ndarray | None = None, sources: bool = True) -> AccFit:
    """The accelerometer fit with R_SP from the gyro fitted with ``gyro_effects`` (the accepted
    ones and the nuisances), its held-out errors and, with ``sources``, every effect's covariance
    by source (see the module docstring)."""
    holds, t_c = seg.holds, seg.t_c
    R_sp, C_rot = sensor_rotation(seg, gyro_effects)
    a = fit_acc(holds, t_c, R_sp, effects, separable=True)
    a.cv = acc_cv(holds, t_c, R_sp, effects, block)
    if not effects or not sources:
        return a
    for e in effects:
        a.effect_cov[e.name] = {"noise": a.cov[a.index(e.name), a.index(e.name)]}
    if q_draws:
        xs = []
        for q in q_draws:
            R_q, _ = sensor_rotation(seg, gyro_effects, model_rates(seg, q))
            xs.append(fit_acc(holds, t_c, R_q, effects, R=matrix_from_quat(q[holds.rows])).x)
        if len(xs) >= 2:
            C = np.atleast_2d(np.cov(np.array(xs).T))
            for e in effects:
                i = a.index(e.name)
                a.effect_cov[e.name]["model"] = C[i, i]
    h = 1e-4
    J = np.stack([(fit_acc(holds, t_c, matrix_from_rotvec(h * d) @ R_sp, effects).x
                   - fit_acc(holds, t_c, matrix_from_rotvec(-h * d) @ R_sp, effects).x) / (2 * h) for d in np.eye(3)], axis=1)
    for e in effects:
        i = a.index(e.name)
        a.effect_cov[e.name]["sensor"] = J[i] @ C_rot @ J[i].T
        a.effect_cov[e.name]["frame"] = np.asarray(e.frame_covariance(a.theta(e.name), frame_base, frame_platform), float)
    return a
