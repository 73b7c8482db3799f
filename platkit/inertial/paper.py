"""The orientation estimator of Burlakov, Latonov and Chertopolokhov (2018), as the paper gives it.

Step 1 of the paper: the gyro and accelerometer are low-pass filtered (cut-off "found
experimentally": here from the spectrum's noise floor, :func:`platkit.inertial.filters.cutoff_from_spectrum`)
and corrected for zero bias and scale. Then:

- q_mod integrates the Poisson (quaternion) equation dq/dt = 1/2 q o omega, sample by sample;
- case A, the platform is still: every component of omega stayed below eps_omega over the last
  T seconds. The accelerometer averaged over T, a~, is turned into the reference frame,
  q_mod o a~ o q_mod^-1, and the rotation delta_q that takes it onto the vertical is applied from
  the left: q~ = delta_q o q_mod;
- case B, rotation about an axis of constant direction: omega kept its direction over T. Inertial
  forces then lie in the plane normal to the axis e_omega, so only the accelerometer's component
  along e_omega is trusted: with alpha_1 the angle between a~ and e_omega and alpha_2 the angle
  between the model gravity a' = q_mod^-1 o g_up o q_mod and e_omega, the model is turned by
  delta_alpha = alpha_1 - alpha_2 about e_omega x a' (in the moving frame): q~ = q_mod o delta_q.

Conventions changed from the paper's, not its method: the paper's accelerometer reads -e_z at rest
in a frame with z down; platkit's reads +|g| along z up, so the reference vector is +e_z. The
paper's case-B delta_q is printed with sin(delta_alpha), cos(delta_alpha); a rotation by
delta_alpha needs the half angles, which is what is used (the full angle would overshoot by 2x).
Both corrections are applied in full whenever their condition holds, as in the paper.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from platkit.errors import BadInput
from platkit.inertial import quat as Q
from platkit.inertial.estimator import OrientationEstimate
from platkit.inertial.filters import cutoff_from_spectrum, lowpass
from platkit.io.imu import ImuStream


@dataclass
class PaperParams:
    """Settings of :func:`estimate_paper`. None: found from the data (said in the result's info).

    ``window_s``: T of cases A and B. ``eps_omega`` (rad/s): the rest threshold on every gyro
    component; found from the data it is capped at ``max_eps_omega`` (a recording that never
    rests must not make slow motion count as rest). ``axis_tolerance`` (rad): how far omega's
    direction may wander over T in case B.
    ``min_rate_case_b`` (rad/s): below it the rotation axis is too noisy to use.
    ``gyr_cutoff_hz``/``acc_cutoff_hz``: the low-pass cut-offs.
    """

    window_s: float = 0.5
    eps_omega: float | None = None
    max_eps_omega: float = math.radians(2.0)
    axis_tolerance: float = math.radians(3.0)
    min_rate_case_b: float = math.radians(10.0)
    gyr_cutoff_hz: float | None = None
    acc_cutoff_hz: float | None = None
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    case_a: bool = True
    case_b: bool = True

    def as_dict(self) -> dict:
        return asdict(self)


def _causal_mean(x: np.ndarray, k: int) -> np.ndarray:
    """Mean of the last k samples (fewer at the start), along axis 0."""
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    idx = np.arange(1, len(x) + 1)
    lo = np.maximum(idx - k, 0)
    return (c[idx] - c[lo]) / (idx - lo)[(...,) + (None,) * (x.ndim - 1)]


def _causal_max(x: np.ndarray, k: int) -> np.ndarray:
    from scipy.ndimage import maximum_filter1d

    # maximum_filter1d centres its window; shift it so that it covers the last k samples
    return maximum_filter1d(x, size=k, axis=0, origin=(k - 1) // 2, mode="nearest")


def rest_threshold(gyr: np.ndarray, rate_hz: float, window_s: float = 2.0, factor: float = 6.0) -> float:
    """eps_omega found from the data: ``factor`` times the gyro noise std of the quietest window.

    ``gyr`` (N, 3) rad/s, bias already removed or not (the std ignores a constant).
    """
    k = max(8, int(window_s * rate_hz))
    if len(gyr) < k:
        raise BadInput(f"need at least {k} samples to find the rest threshold")
    m = _causal_mean(gyr, k)
    m2 = _causal_mean(gyr**2, k)
    var = np.clip(m2 - m**2, 0, None).max(axis=1)[k - 1:]
    j = int(np.argmin(var)) + k - 1
    return float(factor * np.sqrt(var[j - k + 1]) if var[j - k + 1] > 0 else 1e-3)


def estimate_paper(imu: ImuStream, params: PaperParams | None = None) -> OrientationEstimate:
    """Poisson integration with the case A and case B accelerometer corrections.

    Returns q_earth_from_sensor (N, 4); ``rest`` marks the samples where case A held, and
    ``info['case_b']`` counts where case B did. The gyro bias is fixed (``params.gyro_bias``,
    from a calibration or the initial rest): the paper does not estimate it online.
    """
    p = params or PaperParams()
    rate = imu.rate_hz
    dt = imu.dt
    info: dict = {"method": "paper"}
    gyr_fc = p.gyr_cutoff_hz or cutoff_from_spectrum(imu.gyr, rate).cutoff_hz
    acc_fc = p.acc_cutoff_hz or cutoff_from_spectrum(imu.acc, rate).cutoff_hz
    gyr = lowpass(imu.gyr - np.asarray(p.gyro_bias, float), gyr_fc, rate)
    acc = lowpass(imu.acc, acc_fc, rate)
    eps = p.eps_omega if p.eps_omega is not None else min(rest_threshold(imu.gyr, rate), p.max_eps_omega)
    info.update(gyr_cutoff_hz=gyr_fc, acc_cutoff_hz=acc_fc, eps_omega=eps)
    k = max(2, int(round(p.window_s * rate)))
    acc_mean = _causal_mean(acc, k)
    # case A: every component of omega below eps over the last T
    still = _causal_max(np.abs(gyr).max(axis=1), k) < eps
    still[: k - 1] = False
    # case B: omega's direction constant over T (resultant length of unit vectors near 1)
    rate_norm = np.linalg.norm(gyr, axis=1)
    unit = gyr / np.maximum(rate_norm, 1e-12)[:, None]
    u_mean = _causal_mean(unit, k)
    resultant = np.linalg.norm(u_mean, axis=1)
    fast = -_causal_max(-rate_norm, k) > p.min_rate_case_b
    axis_fixed = fast & (resultant > math.cos(p.axis_tolerance)) & ~still
    axis_fixed[: k - 1] = False
    e_omega = u_mean / np.maximum(resultant, 1e-12)[:, None]

    n = imu.n
    out = np.empty((n, 4))
    g = gyr.tolist()
    am = acc_mean.tolist()
    eo = e_omega.tolist()
    # the initial attitude: the first accelerometer average turned onto the vertical
    q = Q.from_two_vectors(am[min(k, n) - 1], (0.0, 0.0, 1.0))
    use_a = still.tolist() if p.case_a else [False] * n
    use_b = axis_fixed.tolist() if p.case_b else [False] * n
    for i in range(n):
        w = g[i]
        if i:
            q = Q.normalize(Q.mul(q, Q.from_rotvec(w[0] * dt, w[1] * dt, w[2] * dt)))
        if use_a[i]:
            v = Q.rotate(q, am[i])
            q = Q.normalize(Q.mul(Q.from_two_vectors(v, (0.0, 0.0, 1.0)), q))
        elif use_b[i]:
            a_t = am[i]
            e = eo[i]
            a_m = Q.rotate(Q.conj(q), (0.0, 0.0, 1.0))  # model gravity (up) in the moving frame
            na = math.sqrt(a_t[0] ** 2 + a_t[1] ** 2 + a_t[2] ** 2)
            alpha1 = math.acos(max(-1.0, min(1.0, (a_t[0] * e[0] + a_t[1] * e[1] + a_t[2] * e[2]) / na)))
            alpha2 = math.acos(max(-1.0, min(1.0, a_m[0] * e[0] + a_m[1] * e[1] + a_m[2] * e[2])))
            d_alpha = alpha1 - alpha2
            nx = e[1] * a_m[2] - e[2] * a_m[1]
            ny = e[2] * a_m[0] - e[0] * a_m[2]
            nz = e[0] * a_m[1] - e[1] * a_m[0]
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
            if nn > 1e-9:
                # gravity seen in the moving frame after q o dq is dq^-1 a' dq: turning a' by
                # +d_alpha about n needs dq = rotation by -d_alpha about n
                s = -d_alpha / nn
                q = Q.normalize(Q.mul(q, Q.from_rotvec(nx * s, ny * s, nz * s)))
        out[i] = q
    out *= np.where(out[:, :1] < 0, -1.0, 1.0)
    info["case_a_samples"] = int(np.sum(use_a))
    info["case_b_samples"] = int(np.sum(use_b))
    info["params"] = p.as_dict()
    return OrientationEstimate(imu.t.copy(), out, np.tile(np.asarray(p.gyro_bias, float), (n, 1)), np.array(use_a), info)
