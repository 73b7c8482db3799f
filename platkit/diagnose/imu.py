"""Diagnosis of an IMU riding on a commanded platform: gyro bias drift and misalignment.

When a session has imu.csv and logged commands, the calibrated model predicts the platform's
orientation at every command (forward kinematics with the calibration's td), so it predicts the
rotation the platform made between two holds. The gyro measured the same rotation. Between the
middles of two consecutive holds (:func:`platkit.inertial.command_aided.held_mask`), segment k of
duration dt_k, the gyro's mean rate y_k (rad/s, sensor axes; its integrated rotation over dt_k)
is compared with the model's mean rate p_k = log(q_a^-1 q_b) / dt_k (platform axes):

    y_k = R_SP p_k + mean of b(t) over the segment + noise

The base model is an aligned sensor (R_SP = I) with a constant bias b0 (a constant gyro bias is
normal and is not a finding). Two effects extend it:

- ``gyro_bias_drift``: b(t) = b0 + d (t - t_c), t_c the middle of the session; d (3) rad/s per s;
- ``imu_misalignment``: R_SP = exp([theta]x), theta (3) rad, a constant rotation of the IMU axes
  against the platform frame (fitted by Gauss-Newton on the exact rotation).

Each is tested as in pose diagnosis: an F test of the extended fit against the current one on
all segments (Holm over the candidates), and a held-out test: the segments are cut into blocks
of consecutive segments in time, the model is fitted on the even blocks and scores the odd ones
and the reverse; accepted when the per-segment held-out squared errors fall (one-sided Wilcoxon
at ``alpha_heldout``) by at least ``min_relative_gain`` of the RMS. Effects are added one at a
time (the better one first). On a clean IMU nothing passes.

The exact rotation composition matters once the bias is large (a bias of 0.01 rad/s over a 4 s
segment that also turns 0.14 rad makes a cross term as large as the noise): the gyro is
integrated with a running bias (the per-hold mean rates, interpolated) removed, and that bias's
integral is added back, so y_k is the mean rate to first order in what remains.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from platkit.diagnose.stats import holm, paired_improvement
from platkit.errors import NotIdentifiable
from platkit.geometry import matrix_from_rotvec, quat_conjugate, quat_multiply, rotvec_from_quat, skew
from platkit.inertial.calibration import integrate_gyro
from platkit.inertial.stream import ImuStream

IMU_EFFECTS = ("gyro_bias_drift", "imu_misalignment")
DEG = 180.0 / np.pi

#: a misalignment smaller than this (deg) is not named. The gyro is compared with the calibrated
#: model's platform frame, and that frame is tied to the parameters the calibration holds at
#: their nominal values (its gauge): a stand built a few tenths of a mm off them turns the model's
#: frame against the real one by a few hundredths of a degree, which the mocap cannot see and a
#: gyro can (0.06-0.08 deg in the simulated stewart sessions of tests/unit/test_diagnose_imu.py)
MIN_ANGLE_DEG = 0.25


@dataclass
class Segments:
    """Segment k: from the middle of hold a to the middle of hold b (consecutive holds)."""

    t_mid: np.ndarray  # (K,) s
    dt: np.ndarray  # (K,) s
    y: np.ndarray  # (K, 3) rad/s, measured mean rate, sensor axes
    p: np.ndarray  # (K, 3) rad/s, model's mean rate, platform axes
    t_c: float  # s, the middle of the session
    hold_bias: np.ndarray  # (H, 3) rad/s, the mean rate of each hold
    hold_t: np.ndarray  # (H,) s
    pairs: np.ndarray  # (K, 2) the command rows (a, b) of each segment


@dataclass
class ImuFit:
    effects: tuple[str, ...]
    b0: np.ndarray
    drift: np.ndarray
    theta: np.ndarray
    cov: np.ndarray  # covariance of the parameters (b0, [drift], [theta]) from the gyro noise
    resid: np.ndarray  # (K, 3) rad/s on all segments
    rss: float
    n_params: int
    cv: np.ndarray | None = None  # (K,) held-out squared error per segment, (rad/s)^2
    model_cov: np.ndarray | None = None  # parameter covariance from the calibrated model's uncertainty (td)

    @property
    def cv_rms(self) -> float:
        return float(np.sqrt(np.mean(self.cv) / 3.0))


@dataclass
class ImuDiagnosis:
    findings: list[dict[str, Any]]
    base: ImuFit
    final: ImuFit
    segments: Segments
    tests: list[dict[str, Any]]
    verdict: str
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"unit": "deg/s", "n_segments": int(len(self.segments.dt)),
                "session_s": float(self.segments.t_mid[-1] - self.segments.t_mid[0] + 0.5 * (self.segments.dt[0] + self.segments.dt[-1])),
                "constant_gyro_bias_deg_s": (self.final.b0 * DEG).tolist(),
                "heldout_rms_base": self.base.cv_rms * DEG, "heldout_rms_final": self.final.cv_rms * DEG,
                "tests": self.tests, "findings": self.findings, "verdict": self.verdict,
                "warnings": list(self.warnings),
                "method": ("mean gyro rate between the middles of consecutive holds against the calibrated model's "
                           "rotation between the commanded poses; F test (Holm over the candidates) and held-out test "
                           "on alternate blocks of consecutive segments (one-sided Wilcoxon)")}


# ---------------------------------------------------------------------------- data
def segments_from_session(imu: ImuStream, t_cmd: np.ndarray, q_cmd: np.ndarray, timing=None) -> Segments:
    """The segments between consecutive holds of a session (see the module docstring)."""
    from platkit.inertial.command_aided import _hold_index, estimate_timing, held_mask

    t_cmd = np.asarray(t_cmd, float)
    timing = timing or estimate_timing(imu, t_cmd, q_cmd)
    held = held_mask(imu.t, t_cmd, timing)
    k = _hold_index(imu.t, t_cmd)
    holds = []
    for i in np.unique(k[held]):
        idx = np.nonzero(held & (k == i))[0]
        if len(idx) >= 10:
            holds.append((int(i), idx))
    if len(holds) < 12:
        raise NotIdentifiable(f"IMU diagnosis: {len(holds)} holds found, at least 12 are needed")
    hold_t = np.array([imu.t[idx].mean() for _, idx in holds])
    hold_b = np.array([imu.gyr[idx].mean(axis=0) for _, idx in holds])
    # running bias: the hold means, interpolated (only to keep the integration linear in the rest)
    run = np.stack([np.interp(imu.t, hold_t, hold_b[:, j]) for j in range(3)], axis=1)
    dt = imu.dt
    cum_run = np.concatenate([np.zeros((1, 3)), np.cumsum(run[1:], axis=0) * dt])
    t_mid, dts, y, p, pairs = [], [], [], [], []
    for (a, ia), (b, ib) in zip(holds[:-1], holds[1:]):
        i0, i1 = int(ia[len(ia) // 2]), int(ib[len(ib) // 2])
        T = imu.t[i1] - imu.t[i0]
        r_s = integrate_gyro(imu.gyr[i0 + 1:i1 + 1] - run[i0 + 1:i1 + 1], dt) + (cum_run[i1] - cum_run[i0])
        r_p = rotvec_from_quat(quat_multiply(quat_conjugate(q_cmd[a]), q_cmd[b]))
        t_mid.append(0.5 * (imu.t[i0] + imu.t[i1]))
        dts.append(T)
        y.append(r_s / T)
        p.append(r_p / T)
        pairs.append((a, b))
    t_mid = np.array(t_mid)
    return Segments(t_mid, np.array(dts), np.array(y), np.array(p), float(0.5 * (t_mid[0] + t_mid[-1])), hold_b, hold_t,
                    np.array(pairs))


def _model_rates(seg: Segments, q_cmd: np.ndarray) -> np.ndarray:
    """(K, 3) rad/s the model's mean rates of ``seg`` with other command orientations."""
    a, b = seg.pairs[:, 0], seg.pairs[:, 1]
    return rotvec_from_quat(quat_multiply(quat_conjugate(q_cmd[a]), q_cmd[b])) / seg.dt[:, None]


# ---------------------------------------------------------------------------- fitting
def _fit(seg: Segments, effects: tuple[str, ...], rows: np.ndarray | None = None, iterations: int = 4) -> ImuFit:
    """Weighted least squares (weight dt_k: the noise of a mean rate falls as 1/sqrt(dt)) of the
    model with ``effects`` on the segments ``rows`` (default all); residuals on all segments."""
    rows = np.ones(len(seg.dt), bool) if rows is None else rows
    drift, misal = "gyro_bias_drift" in effects, "imu_misalignment" in effects
    K = len(seg.dt)
    theta = np.zeros(3)
    w = np.sqrt(seg.dt / seg.dt.mean())
    tau = seg.t_mid - seg.t_c
    for _ in range(iterations if misal else 1):
        R = matrix_from_rotvec(theta)
        Rp = seg.p @ R.T
        cols = [np.broadcast_to(np.eye(3), (K, 3, 3))]
        if drift:
            cols.append(tau[:, None, None] * np.eye(3)[None])
        if misal:
            cols.append(-np.einsum("kij,jl->kil", skew(Rp), np.eye(3)))  # d(R p)/d(dtheta) = -[R p]x
        A = np.concatenate(cols, axis=2)  # (K, 3, n)
        rhs = seg.y - Rp
        if misal:
            rhs = rhs + np.einsum("kij,j->ki", A[:, :, -3:], theta)
        Aw = (A * w[:, None, None])[rows].reshape(-1, A.shape[2])
        bw = (rhs * w[:, None])[rows].reshape(-1)
        x = np.linalg.lstsq(Aw, bw, rcond=None)[0]
        if misal:
            theta = x[-3:].copy()
    R = matrix_from_rotvec(theta)
    model = seg.p @ R.T + x[:3] + (tau[:, None] * x[3:6] if drift else 0.0)
    resid = seg.y - model
    n = len(x)
    rss = float(np.sum((resid * w[:, None])[rows] ** 2))
    dof = max(3 * int(rows.sum()) - n, 1)
    cov = np.linalg.pinv(Aw.T @ Aw) * rss / dof
    return ImuFit(tuple(effects), x[:3], x[3:6] if drift else np.zeros(3), theta, cov, resid, rss, n)


def _blocks(K: int, block: int) -> np.ndarray:
    """(K,) bool: segment k in an even block of ``block`` consecutive segments."""
    return (np.arange(K) // block) % 2 == 0


def _cv(seg: Segments, effects: tuple[str, ...], block: int) -> np.ndarray:
    even = _blocks(len(seg.dt), block)
    out = np.empty(len(seg.dt))
    for train in (even, ~even):
        f = _fit(seg, effects, train)
        out[~train] = np.sum(f.resid[~train] ** 2, axis=1)
    return out


def _index(effects: tuple[str, ...], effect: str) -> slice:
    """Where ``effect``'s three parameters sit in the fit's vector (b0, [drift], [theta])."""
    if effect == "gyro_bias_drift":
        return slice(3, 6)
    return slice(3 + 3 * ("gyro_bias_drift" in effects), 6 + 3 * ("gyro_bias_drift" in effects))


def _vec(f: ImuFit) -> np.ndarray:
    return np.concatenate([f.b0] + ([f.drift] if "gyro_bias_drift" in f.effects else [])
                          + ([f.theta] if "imu_misalignment" in f.effects else []))


def _model_cov(seg: Segments, effects: tuple[str, ...], p_draws: list[np.ndarray] | None) -> np.ndarray:
    """Covariance of the fit's parameters due to the calibrated model's own uncertainty: the
    spread of the refits with the model's rotations from td drawn from its covariance."""
    n = 3 + 3 * len(effects)
    if not p_draws:
        return np.zeros((n, n))
    xs = np.array([_vec(_fit(replace(seg, p=p), effects)) for p in p_draws])
    return np.atleast_2d(np.cov(xs.T))


def _f_test(small: ImuFit, big: ImuFit, n_obs: int) -> tuple[float, float]:
    k = big.n_params - small.n_params
    dof = n_obs - big.n_params
    F = ((small.rss - big.rss) / k) / max(big.rss / dof, 1e-300)
    return float(F), float(stats.f.sf(F, k, dof))


# ---------------------------------------------------------------------------- findings
def _finding(effect: str, fit: ImuFit, before: ImuFit, p_held: float, p_f: float, seg: Segments) -> dict[str, Any]:
    cov = fit.cov + (fit.model_cov if fit.model_cov is not None else 0.0)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    span = (float(seg.t_mid[0] - 0.5 * seg.dt[0]), float(seg.t_mid[-1] + 0.5 * seg.dt[-1]))
    a, b = before.cv_rms * DEG, fit.cv_rms * DEG
    if effect == "gyro_bias_drift":
        d, sd = fit.drift * DEG * 60.0, std[3:6] * DEG * 60.0
        params = {f"drift_{c}": {"value": float(v), "std": float(s), "unit": "deg/s per min"}
                  for c, v, s in zip("xyz", d, sd)}
        params.update({f"bias_{c}": {"value": float(v), "std": float(s), "unit": "deg/s"}
                       for c, v, s in zip("xyz", fit.b0 * DEG, std[:3] * DEG)})
        where = {"sensor": "gyro", "time_s": [round(span[0], 3), round(span[1], 3)], "reference_time_s": round(seg.t_c, 3),
                 "frame": "sensor axes"}
        change = float(np.linalg.norm(fit.drift) * (span[1] - span[0]) * DEG)
        evidence = (f"The gyro bias changes by {change:.3g} deg/s over the {span[1] - span[0]:.0f} s session "
                    f"({np.linalg.norm(d):.3g} deg/s per min; bias at {seg.t_c:.0f} s: "
                    f"{', '.join(f'{v:.3g}' for v in fit.b0 * DEG)} deg/s): a bias drifting linearly predicts the held-out "
                    f"segments' mean rate with RMS {a:.3g} -> {b:.3g} deg/s over {len(seg.dt)} segments "
                    f"(paired Wilcoxon p = {p_held:.2g}; F test Holm p = {p_f:.2g}).")
    else:
        ang = fit.theta * DEG
        n_off = len(cov) - 3
        sd = std[n_off:] * DEG
        params = {f"angle_{c}": {"value": float(v), "std": float(s), "unit": "deg"} for c, v, s in zip("xyz", ang, sd)}
        total = float(np.linalg.norm(ang))
        J = ang / total if total > 0 else np.zeros(3)
        tsd = float(np.sqrt(J @ cov[n_off:, n_off:] @ J)) * DEG
        params["angle"] = {"value": total, "std": tsd, "unit": "deg"}
        where = {"sensor": "gyro", "frame": "sensor from platform, rotation vector",
                 "axis": [round(float(v), 4) for v in J]}
        evidence = (f"The gyro's rotations between holds are the model's turned by {total:.3g} deg "
                    f"(rotation vector {', '.join(f'{v:.3g}' for v in ang)} deg, IMU axes against the platform's): "
                    f"modelling the rotation predicts the held-out segments' mean rate with RMS {a:.3g} -> {b:.3g} deg/s "
                    f"over {len(seg.dt)} segments (paired Wilcoxon p = {p_held:.2g}; F test Holm p = {p_f:.2g}).")
    return {"effect": effect, "where": where, "parameters": params, "heldout_rms_before": a, "heldout_rms_after": b,
            "unit": "deg/s", "evidence": evidence, "p_heldout": p_held, "p_screen": p_f, "warnings": []}


def diagnose_segments(seg: Segments, alpha: float = 0.01, alpha_heldout: float = 0.05, block: int = 4,
                      min_relative_gain: float = 0.02, p_draws: list[np.ndarray] | None = None,
                      min_angle_deg: float = MIN_ANGLE_DEG) -> ImuDiagnosis:
    """Forward selection of the IMU effects on the segments of one session. ``p_draws``: the
    model's mean rates (K, 3) recomputed with td drawn from the calibration's covariance; an
    effect must also exceed what they allow (Wald test with both covariances at ``alpha``). A
    misalignment below ``min_angle_deg`` is not named (see MIN_ANGLE_DEG)."""
    cur = _fit(seg, ())
    cur.model_cov = _model_cov(seg, (), p_draws)
    cur.cv = _cv(seg, (), block)
    base = cur
    n_obs = 3 * len(seg.dt)
    findings, tests = [], []
    while True:
        left = [e for e in IMU_EFFECTS if e not in cur.effects]
        if not left:
            break
        cands = []
        for e in left:
            f = _fit(seg, cur.effects + (e,))
            f.cv = _cv(seg, f.effects, block)
            F, p = _f_test(cur, f, n_obs)
            cands.append((e, f, F, p))
        p_adj = holm(np.array([c[3] for c in cands]))
        rows = []
        for (e, f, F, p), pa in zip(cands, p_adj):
            ph = paired_improvement(cur.cv, f.cv)
            gain = 1.0 - f.cv_rms / cur.cv_rms
            # larger than the calibrated model's own uncertainty can make it? (Wald, both covariances)
            f.model_cov = _model_cov(seg, f.effects, p_draws)
            i = _index(f.effects, e)
            C = f.cov[i, i] + f.model_cov[i, i]
            v = _vec(f)[i]
            wald = float(v @ np.linalg.pinv(C) @ v)
            pw = float(stats.chi2.sf(wald, 3))
            big = e != "imu_misalignment" or np.linalg.norm(f.theta) * DEG >= min_angle_deg
            rows.append({"effect": e, "F": F, "p_adjusted": float(pa), "p_heldout": ph, "heldout_rms_before": cur.cv_rms * DEG,
                         "heldout_rms_after": f.cv_rms * DEG, "relative_gain": gain, "p_beyond_model": pw,
                         "size": float(np.linalg.norm(v)) * (DEG if e == "imu_misalignment" else DEG * 60.0),
                         "size_unit": "deg" if e == "imu_misalignment" else "deg/s per min",
                         "accepted": bool(pa < alpha and ph < alpha_heldout and gain >= min_relative_gain and pw < alpha
                                          and big)})
        tests.append({"round": len(findings) + 1, "candidates": rows})
        ok = [(r["heldout_rms_after"], i) for i, r in enumerate(rows) if r["accepted"]]
        if not ok:
            break
        i = min(ok)[1]
        e, f = cands[i][0], cands[i][1]
        findings.append(_finding(e, f, cur, rows[i]["p_heldout"], rows[i]["p_adjusted"], seg))
        cur = f
    # each finding's parameters from the final model (the other effect fitted with it)
    for fd in findings:
        fd.update({k: v for k, v in _finding(fd["effect"], cur, cur, fd["p_heldout"], fd["p_screen"], seg).items()
                   if k == "parameters"})
    return ImuDiagnosis(findings, base, cur, seg, tests, _verdict(findings, base, cur))


def _verdict(findings, base: ImuFit, final: ImuFit) -> str:
    if not findings:
        return (f"IMU: no gyro effect found; a constant gyro bias ({', '.join(f'{v:.3g}' for v in base.b0 * DEG)} deg/s) "
                f"and the model's rotations leave a held-out RMS of {base.cv_rms * DEG:.3g} deg/s, and neither a "
                "drifting bias nor a misalignment predicts held-out segments significantly better.")
    names = ", ".join(f["effect"] for f in findings)
    return (f"IMU: the gyro shows {names}; modelling {'it' if len(findings) == 1 else 'them'} brings the held-out "
            f"mean-rate RMS from {base.cv_rms * DEG:.3g} to {final.cv_rms * DEG:.3g} deg/s.")


def td_covariance(cal) -> np.ndarray:
    """(n_td, n_td) covariance of a Calibration's td: the estimator's full covariance when the
    calibration was fitted in this process, else its stds (NaN: held or fixed, 0)."""
    n = len(cal.td)
    ex = getattr(cal, "extras", None) or {}
    if "cov" in ex and "active" in ex:
        active = np.asarray(ex["active"], bool)
        full = np.zeros((len(active), len(active)))
        idx = np.nonzero(active)[0]
        full[np.ix_(idx, idx)] = ex["cov"]
        return full[:n, :n]
    return np.diag(np.nan_to_num(np.asarray(cal.td_std, float)) ** 2)


def diagnose_imu(spec, td, t_cmd: np.ndarray, U: np.ndarray, imu: ImuStream, td_cov: np.ndarray | None = None,
                 alpha: float = 0.01, alpha_heldout: float = 0.05, block: int = 4, draws: int = 32,
                 seed: int = 0) -> ImuDiagnosis:
    """Gyro diagnosis of a session: ``spec`` and ``td`` the calibrated stand, ``td_cov`` its
    covariance (:func:`td_covariance`; None: the model is taken as exact), ``t_cmd`` (M,) s and
    ``U`` (M, n_u) SI the logged commands, ``imu`` the stream. See the module docstring."""
    from platkit.inertial.command_aided import command_poses
    from platkit.kinematics import PlatformModel

    model = PlatformModel(spec)
    U = np.asarray(U, float)
    td = np.asarray(td, float)
    q_cmd = command_poses(model, U, td=td)
    seg = segments_from_session(imu, np.asarray(t_cmd, float), q_cmd)
    p_draws = None
    if td_cov is not None and np.any(np.asarray(td_cov) != 0):
        rng = np.random.default_rng(seed)
        L = _sqrt_psd(np.asarray(td_cov, float))
        p_draws = []
        for _ in range(draws):
            fb = model.forward_batch(U, td=td + L @ rng.standard_normal(len(td)), strict=False)
            if not np.all(fb.converged):
                continue
            p_draws.append(_model_rates(seg, fb.q))
    return diagnose_segments(seg, alpha, alpha_heldout, block, p_draws=p_draws)


def _sqrt_psd(C: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    return V * np.sqrt(np.clip(w, 0, None))
