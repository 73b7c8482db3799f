"""Diagnosis of an IMU riding on a commanded platform: which IMU effects the session shows.

When a session has imu.csv and logged commands, the calibrated model predicts the platform's
orientation at every command (forward kinematics with the calibration's td), so it predicts the
rotation the platform made between two holds, and how gravity lies in the sensor at every hold.
The modules behind :func:`diagnose_imu`:

- :mod:`~platkit.diagnose.imu.segments`: the gyro's mean rates between consecutive holds and the
  accelerometer at the holds;
- :mod:`~platkit.diagnose.imu.gyro`: the gyro model and the gyro effects (e.g. a drifting bias,
  a misaligned IMU), fitted on the segments;
- :mod:`~platkit.diagnose.imu.accelerometer`: the accelerometer model and its effects (e.g. a base
  tilted against the model's vertical), fitted on the holds;
- :mod:`~platkit.diagnose.imu.frames`: how far the model's own frames can be off (the
  parameters the calibration held at nominal), allowed for in the tests.

The effects are the installed :class:`platkit.effects.ImuEffect` plugins (built-in ones:
plugins/platkit_effects/imu.py; an outside package adds its own through the same hook). Each is
tested as in pose diagnosis: an F test of the extended fit against the current one (Holm over the
candidates of the round), and a held-out test: the segments (gyro) or the holds (accelerometer)
are cut into blocks of consecutive ones in time, the model is fitted on the even blocks and scores
the odd ones and the reverse; accepted when the per-segment (per-hold) held-out squared errors
fall (one-sided Wilcoxon at ``alpha_heldout``) by at least ``min_relative_gain`` of the RMS. A
Wald test then asks whether the parameters exceed what the noise, the calibrated model's
uncertainty and its frames allow, and the effect's floor (``min_size``) applies. Effects are added
one at a time (the largest held-out gain first). A nuisance effect (the IMU's mounting) is fitted
in every other gyro effect's test, named or not; the accelerometer takes R_SP from the gyro fitted
with the nuisances.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from platkit.diagnose.imu.accelerometer import AccFit, acc_state, up_in_sensor
from platkit.diagnose.imu.fitting import f_test
from platkit.diagnose.imu.frames import frame_gauge, held_parameter_std
from platkit.diagnose.imu.gyro import GyroFit, full_fit, noise_cov, with_nuisances
from platkit.diagnose.imu.segments import Segments, model_rates, segments_from_session
from platkit.diagnose.stats import holm, paired_improvement
from platkit.effects import Effect, ImuEffect, imu_effects
from platkit.inertial.command_aided import command_poses
from platkit.io.calibration import Calibration
from platkit.io.imu import ImuStream
from platkit.kinematics import PlatformModel
from platkit.plugins import effect_library

DEG = 180.0 / np.pi
#: the units findings are shown in, by sensor: (name, scale from SI)
HELDOUT_UNIT = {"gyro": ("deg/s", DEG), "accelerometer": ("m/s^2", 1.0)}

__all__ = ["DEG", "ImuDiagnosis", "diagnose_imu", "diagnose_segments", "td_covariance", "segments_from_session",
           "frame_gauge", "held_parameter_std", "up_in_sensor", "GyroFit", "AccFit", "Segments"]


@dataclass
class ImuDiagnosis:
    findings: list[dict[str, Any]]
    base: GyroFit
    final: GyroFit
    segments: Segments
    tests: list[dict[str, Any]]
    verdict: str
    warnings: list[str] = field(default_factory=list)
    acc_base: AccFit | None = None
    acc_final: AccFit | None = None
    not_separable: list[dict[str, Any]] = field(default_factory=list)
    frame: dict[str, Any] = field(default_factory=dict)
    entries: dict[str, Any] = field(default_factory=dict)  # what the findings add to calibration.yaml

    def to_dict(self) -> dict[str, Any]:
        seg = self.segments
        out = {"unit": "deg/s", "n_segments": int(len(seg.dt)), "session_s": float(seg.span_s[1] - seg.span_s[0]),
               "constant_gyro_bias_deg_s": (self.final.b0 * DEG).tolist(),
               "heldout_rms_base": self.base.cv_rms * DEG, "heldout_rms_final": self.final.cv_rms * DEG,
               "tests": self.tests, "findings": self.findings, "verdict": self.verdict,
               "warnings": list(self.warnings),
               "method": ("mean gyro rate between the middles of consecutive holds against the calibrated model's "
                          "rotation between the commanded poses; mean specific force of each hold against gravity "
                          "turned by the model's orientation; F test (Holm over the candidates) and held-out test on "
                          "alternate blocks of consecutive segments or holds (one-sided Wilcoxon); Wald test against "
                          "the noise, the calibration's uncertainty and its gauge")}
        if self.acc_final is not None:
            a, b = self.acc_base, self.acc_final
            out["accelerometer"] = {
                "unit": "m/s^2", "n_holds": int(len(seg.holds.rows)),
                "constant_bias_m_s2": b.bias.tolist(), "gravity_m_s2": b.scale.tolist(),
                "heldout_rms_base": a.cv_rms, "heldout_rms_final": b.cv_rms,
                "separability": {r["effect"]: float(r["separability"]) for t in self.tests[:1] for r in t["candidates"]
                                 if r.get("sensor") == "accelerometer"},
                "sensor_from_platform_deg": (b.sensor_rotation * DEG).tolist(),
                "note": ("gravity_m_s2: the gravity each axis reads (local gravity times its scale; on an axis that "
                         "stays near vertical it trades with that axis's bias, and only their sum is measured); "
                         "sensor_from_platform_deg: the rotation of the IMU axes against the model's platform "
                         "frame the gyro sees (rotation vector), used for the accelerometer")}
        out["not_separable"] = list(self.not_separable)
        if self.frame:
            out["model_frame"] = dict(self.frame)
        return out

    def calibration_entry(self) -> dict[str, Any]:
        """What the accepted findings add to the calibrated model, SI, for calibration.yaml's
        ``imu`` mapping (empty without findings)."""
        out = dict(self.entries)
        if out:
            out["source"] = "platkit diagnose: the IMU findings accepted on this session (platkit.diagnose.imu)"
        return out


# ---------------------------------------------------------------------------- selection
@dataclass
class _Candidate:
    effect: ImuEffect
    fit: Any  # GyroFit or AccFit with the effect
    before: Any  # the fit it is tested against
    F: float
    p: float


def _context(e: ImuEffect, seg: Segments, fit, before, p_held: float, p_f: float) -> dict[str, Any]:
    """What an effect's report and calibration entry may use (see :meth:`ImuEffect.report`)."""
    unit, scale = HELDOUT_UNIT[e.sensor]
    gyro = e.sensor == "gyro"
    b0, b0_std = np.zeros(3), np.zeros(3)
    if gyro:
        C = fit.cov[:3, :3] + (fit.model_cov[:3, :3] if fit.model_cov is not None else 0.0)
        b0, b0_std = fit.b0.copy(), np.sqrt(np.clip(np.diag(C), 0, None))
    return {"sensor": e.sensor, "n": int(len(seg.dt) if gyro else len(seg.holds.rows)), "span_s": seg.span_s,
            "t_ref": float(seg.t_c), "b0": b0, "b0_std": b0_std, "heldout_before": before.cv_rms * scale,
            "heldout_after": fit.cv_rms * scale, "heldout_unit": unit, "p_heldout": p_held, "p_screen": p_f,
            "separability": float(fit.separability.get(e.name, float("nan")))}


def _effect_cov(e: ImuEffect, fit, frame_base, frame_platform) -> np.ndarray:
    """(n, n) SI: the effect's covariance from every source (noise, model, frames; the sensor
    rotation for an accelerometer effect)."""
    if e.sensor == "gyro":
        return noise_cov(fit, e.name) + e.frame_covariance(fit.theta(e.name), frame_base, frame_platform)
    return fit.total_cov(e.name)


def _finding(e: ImuEffect, seg: Segments, fit, before, p_held: float, p_f: float, frame_base, frame_platform):
    theta = fit.theta(e.name)
    C = _effect_cov(e, fit, frame_base, frame_platform)
    ctx = _context(e, seg, fit, before, p_held, p_f)
    rep = e.report(theta, C, ctx)
    out = {"effect": e.finding_name, "where": rep["where"], "parameters": rep["parameters"],
           "heldout_rms_before": ctx["heldout_before"], "heldout_rms_after": ctx["heldout_after"],
           "unit": ctx["heldout_unit"], "evidence": rep["evidence"], "p_heldout": p_held, "p_screen": p_f,
           "warnings": []}
    if e.sensor == "accelerometer":
        out["separability"] = ctx["separability"]
    return out, e.calibration_entry(theta, C, ctx)


def diagnose_segments(seg: Segments, alpha: float = 0.01, alpha_heldout: float = 0.05, block: int = 4,
                      min_relative_gain: float = 0.02, q_draws: list[np.ndarray] | None = None,
                      frame_base: np.ndarray | None = None, frame_platform: np.ndarray | None = None,
                      library: dict[str, Effect] | None = None) -> ImuDiagnosis:
    """Forward selection of the IMU effects of ``library`` (default: every installed one) on the
    segments (and holds) of one session. ``q_draws``: the model's command orientations (M, 4)
    recomputed with td drawn from the calibration's covariance; ``frame_base``,
    ``frame_platform`` (3, 3) rad^2: how far the model's frames can be turned against the real
    ones (:func:`frame_gauge`). An effect must exceed what they allow (Wald test with every
    covariance at ``alpha``) and its ``min_size``; an effect is not tested where its separability
    is below its ``min_separability``."""
    effects = list(imu_effects(effect_library() if library is None else library).values())
    has_acc = seg.holds is not None
    gyro_all = tuple(e for e in effects if e.sensor == "gyro")
    acc_all = tuple(e for e in effects if e.sensor == "accelerometer") if has_acc else ()
    nuisances = tuple(e for e in gyro_all if e.nuisance)
    p_draws = [model_rates(seg, q) for q in q_draws] if q_draws else None
    cur = full_fit(seg, (), block, p_draws)
    base = cur
    acc = acc_state(seg, nuisances, (), block) if has_acc else None
    acc_base = acc
    acc_with: tuple = nuisances
    findings, tests, not_separable, entries = [], [], [], {}
    accepted: list[tuple[ImuEffect, dict]] = []  # (effect, its finding)

    def acc_fit(gyro_effects, acc_effects):
        return acc_state(seg, with_nuisances(gyro_effects, nuisances), acc_effects, block, q_draws, frame_base,
                         frame_platform)

    while True:
        left = [e for e in gyro_all if e not in cur.effects] + [e for e in acc_all if e not in acc.effects]
        if not left:
            break
        if any(e.sensor == "accelerometer" for e in left):
            acc = acc_fit(cur.effects, acc.effects)  # R_SP from the gyro model of this round
            acc_with = cur.effects
        cands: list[_Candidate] = []
        for e in left:
            if e.sensor == "accelerometer":
                f = acc_fit(cur.effects, acc.effects + (e,))
                F, p = f_test(acc, f, 3 * len(seg.holds.rows))
                cands.append(_Candidate(e, f, acc, F, p))
            else:
                with_n = with_nuisances(cur.effects, nuisances)
                before = cur if e.nuisance or with_n == cur.effects else full_fit(seg, with_n, block)
                f = full_fit(seg, before.effects + (e,), block, p_draws)
                F, p = f_test(before, f, 3 * len(seg.dt))
                cands.append(_Candidate(e, f, before, F, p))
        separable = {c.effect.name: c.fit.separability.get(c.effect.name, 1.0) >= c.effect.min_separability
                     for c in cands}
        tested = [c for c in cands if separable[c.effect.name]]
        p_adj = dict(zip([c.effect.name for c in tested], holm(np.array([c.p for c in tested]))))
        rows = []
        for c in cands:
            e, f, before = c.effect, c.fit, c.before
            v = f.theta(e.name)
            C = _effect_cov(e, f, frame_base, frame_platform)
            dof = e.n_params
            size = e.size(v)
            unit, scale = HELDOUT_UNIT[e.sensor]
            ph = paired_improvement(before.cv, f.cv)
            gain = 1.0 - f.cv_rms / before.cv_rms
            wald = float(v @ np.linalg.pinv(C) @ v)
            pw = float(stats.chi2.sf(wald, dof))
            # the smallest size the Wald test lets through in the worst direction, and the floor
            detectable = float(np.sqrt(stats.chi2.ppf(1 - alpha, dof) * max(np.linalg.eigvalsh(C)[-1], 0.0))) * e.display_scale
            detectable = max(detectable, e.min_size)
            row = {"effect": e.finding_name, "sensor": e.sensor, "F": c.F, "p_adjusted": float(p_adj.get(e.name, 1.0)),
                   "p_heldout": ph, "heldout_rms_before": before.cv_rms * scale, "heldout_rms_after": f.cv_rms * scale,
                   "heldout_unit": unit, "relative_gain": gain, "p_beyond_model": pw, "size": size,
                   "size_unit": e.display_unit, "detectable_size": detectable,
                   "separability": float(f.separability.get(e.name, float("nan")))}
            if e.sensor == "accelerometer":
                row["std_by_source"] = {k: (np.sqrt(np.clip(np.diag(cc), 0, None)) * e.display_scale).tolist()
                                        for k, cc in f.effect_cov.get(e.name, {}).items()}
            if not separable[e.name]:
                row.update(not_separable=True, accepted=False)
                if not any(x["effect"] == e.finding_name for x in not_separable):
                    not_separable.append(_not_separable(e, row["separability"]))
            else:
                row["accepted"] = bool(row["p_adjusted"] < alpha and ph < alpha_heldout and gain >= min_relative_gain
                                       and pw < alpha and size >= e.min_size)
            rows.append(row)
        tests.append({"round": len(accepted) + 1, "candidates": rows})
        ok = [(r["relative_gain"], i) for i, r in enumerate(rows) if r["accepted"]]
        if not ok:
            break
        i = max(ok)[1]
        c = cands[i]
        fd, _ = _finding(c.effect, seg, c.fit, c.before, rows[i]["p_heldout"], rows[i]["p_adjusted"], frame_base,
                         frame_platform)
        accepted.append((c.effect, fd))
        if c.effect.sensor == "accelerometer":
            acc, acc_with = c.fit, cur.effects
        elif c.fit.effects == cur.effects + (c.effect,):
            cur = c.fit
        else:  # the nuisances were fitted for the test only: the model goes on without them
            cur = full_fit(seg, cur.effects + (c.effect,), block, p_draws)
    if has_acc and acc.effects and acc_with != cur.effects:
        acc = acc_fit(cur.effects, acc.effects)  # with R_SP from the final gyro model
    # each finding's parameters from the final model (the other effects fitted with it)
    for e, fd in accepted:
        if e.sensor == "accelerometer":
            fit, before = acc, acc_base
        else:
            fit = cur if e.nuisance else full_fit(seg, with_nuisances(cur.effects, nuisances), block, p_draws)
            before = fit
        final, entry = _finding(e, seg, fit, before, fd["p_heldout"], fd["p_screen"], frame_base, frame_platform)
        fd["parameters"] = final["parameters"]
        findings.append(fd)
        entries.update(entry)
    return ImuDiagnosis(findings, base, cur, seg, tests, _verdict(accepted, base, cur, acc_base, acc, tests, effects),
                        acc_base=acc_base if has_acc else None, acc_final=acc if has_acc else None,
                        not_separable=not_separable, entries=entries)


def _not_separable(e: ImuEffect, sep: float) -> dict[str, Any]:
    where = {"frame": "base", "from": "accelerometer"} if e.sensor == "accelerometer" else {"sensor": e.sensor}
    what = "holds" if e.sensor == "accelerometer" else "segments"
    return {"effect": e.finding_name, "where": where, "separability": float(sep),
            "why": (f"the platform turns too little between {what}: {100 * sep:.2g}% of the signature of "
                    f"{e.name} is beyond what the {e.sensor}'s bias can take (at least {100 * e.min_separability:.2g}% "
                    "is needed)")}


def _verdict(accepted, base: GyroFit, final: GyroFit, acc_base: AccFit | None, acc: AccFit | None, tests,
             effects) -> str:
    gyro = [fd["effect"] for e, fd in accepted if e.sensor == "gyro"]
    if gyro:
        text = (f"IMU: the gyro shows {', '.join(gyro)}; modelling {'it' if len(gyro) == 1 else 'them'} brings the "
                f"held-out mean-rate RMS from {base.cv_rms * DEG:.3g} to {final.cv_rms * DEG:.3g} deg/s.")
    else:
        names = " nor ".join(e.finding_name for e in effects if e.sensor == "gyro") or "any gyro effect"
        text = (f"IMU: no gyro effect found; a constant gyro bias ({', '.join(f'{v:.3g}' for v in base.b0 * DEG)} deg/s) "
                f"and the model's rotations leave a held-out RMS of {base.cv_rms * DEG:.3g} deg/s, and neither "
                f"{names} predicts held-out segments significantly better.")
    if acc is None:
        return text
    for e, fd in accepted:
        if e.sensor == "accelerometer":
            text += (f" The accelerometer shows {fd['effect']}: {e.headline(fd['parameters'])}; modelling it brings the "
                     f"held-out specific-force RMS at the holds from {acc_base.cv_rms:.3g} to {acc.cv_rms:.3g} m/s^2.")
    named = {fd["effect"] for e, fd in accepted if e.sensor == "accelerometer"}
    for e in effects:
        if e.sensor != "accelerometer" or e.finding_name in named:
            continue
        row = next((r for t in tests[::-1] for r in t["candidates"] if r["effect"] == e.finding_name), None)
        if row is None:
            continue
        label = e.finding_name.replace("_", " ")
        if row.get("not_separable"):
            text += (f" A {label} cannot be told from the accelerometer's bias on these holds (separability "
                     f"{row['separability']:.2g}, at least {e.min_separability:g} needed): the platform turns too "
                     "little between them; not tested.")
        else:
            text += (f" The accelerometer shows no {label} beyond what the model's frame allows (estimate "
                     f"{row['size']:.2g} {row['size_unit']}; held-out specific-force RMS {row['heldout_rms_before']:.3g} -> "
                     f"{row['heldout_rms_after']:.3g} m/s^2, p = {row['p_heldout']:.2g}; beyond the calibration's "
                     f"uncertainty p = {row['p_beyond_model']:.2g}).")
    return text


# ---------------------------------------------------------------------------- a session
def td_covariance(cal: Calibration) -> np.ndarray:
    """(n_td, n_td) covariance of a Calibration's td: the estimator's full covariance when the
    calibration was fitted in this process, else its stds (NaN: held or fixed, 0)."""
    n = len(cal.td)
    fit = cal.fit
    if fit is not None and fit.cov is not None and fit.active is not None:
        active = np.asarray(fit.active, bool)
        full = np.zeros((len(active), len(active)))
        idx = np.nonzero(active)[0]
        full[np.ix_(idx, idx)] = fit.cov
        return full[:n, :n]
    return np.diag(np.nan_to_num(np.asarray(cal.td_std, float)) ** 2)


def diagnose_imu(spec, td, t_cmd: np.ndarray, U: np.ndarray, imu: ImuStream, td_cov: np.ndarray | None = None,
                 td_status=None, alpha: float = 0.01, alpha_heldout: float = 0.05, block: int = 4, draws: int = 32,
                 seed: int = 0, library: dict[str, Effect] | None = None) -> ImuDiagnosis:
    """IMU diagnosis of a session: ``spec`` and ``td`` the calibrated stand, ``td_cov`` its
    covariance (:func:`td_covariance`; None: the model is taken as exact), ``td_status`` the
    calibration's parameter statuses (None: its frames are taken as exact; else the parameters
    'held_at_nominal' make the allowance of :func:`frame_gauge`), ``t_cmd`` (M,) s and ``U``
    (M, n_u) SI the logged commands, ``imu`` the stream, ``library`` the effects (default: every
    installed one; the IMU effects among them are tested). See the module docstring."""
    model = PlatformModel(spec)
    U = np.asarray(U, float)
    td = np.asarray(td, float)
    q_cmd = command_poses(model, U, td=td)
    seg = segments_from_session(imu, np.asarray(t_cmd, float), q_cmd)
    q_draws = None
    if td_cov is not None and np.any(np.asarray(td_cov) != 0):
        rng = np.random.default_rng(seed)
        L = _sqrt_psd(np.asarray(td_cov, float))
        q_draws = []
        for _ in range(draws):
            fb = model.forward_batch(U, td=td + L @ rng.standard_normal(len(td)), strict=False)
            if not np.all(fb.converged):
                continue
            q_draws.append(fb.q)
    frame_base = frame_platform = None
    frame: dict[str, Any] = {}
    if td_status is not None:
        rows = np.unique(seg.holds.rows)
        frame_base, frame_platform, n_held = frame_gauge(spec, td, U[rows], td_status, model)
        frame = {"held_parameters": n_held,
                 "base_tilt_std_deg": (np.sqrt(np.diag(frame_base)[:2]) * DEG).tolist(),
                 "platform_rotation_std_deg": (np.sqrt(np.diag(frame_platform)) * DEG).tolist(),
                 "note": ("how far the parameters the calibration held at nominal can turn the model's base and "
                          "platform frames against the real stand's, for held parameters off by 2 mm or 2 mrad "
                          "(1 sigma): allowed for in the Wald tests")}
    d = diagnose_segments(seg, alpha, alpha_heldout, block, q_draws=q_draws, frame_base=frame_base,
                          frame_platform=frame_platform, library=library)
    d.frame = frame
    return d


def _sqrt_psd(C: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    return V * np.sqrt(np.clip(w, 0, None))
