"""What a finding carries beside its name: its signature (each pose's error along the term, before
and after), its parameters as calibration.yaml stores them, the evidence sentence, and the scores
of a separate held-out recording."""
from __future__ import annotations

from typing import Any

import numpy as np

from platkit.calibrate.estimate import point_errors
from platkit.diagnose.fitting import Finding, Fit, _fmt_rms, _where_text
from platkit.diagnose.stats import paired_improvement
from platkit.effects import with_history
from platkit.io.calibration import Calibration
from platkit.model import PlatformSpec, length_scale
from platkit.poses import PoseSet
from platkit.terms import ModelTerm


def _signature(J: np.ndarray, r: np.ndarray, theta: np.ndarray | None, sign: np.ndarray) -> np.ndarray:
    """(N,) each pose's measured-minus-model error along the term's signature (m): r_n (M*3)
    projected on J_n theta_hat, signed by the term's own offset at that pose (``sign``), so that
    it follows the regressor (a backlash's two directions fall on two sides of zero)."""
    N = J.shape[0]
    Jn = np.nan_to_num(J.reshape(N, -1, J.shape[-1]))
    d = Jn @ (theta if theta is not None and np.linalg.norm(theta) > 0 else np.ones(J.shape[-1]))
    rn = np.nan_to_num(r.reshape(N, -1))
    size = np.linalg.norm(d, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(size > 0, -np.sum(rn * d, axis=1) / size * sign, np.nan)

def _offset_sign(term: ModelTerm, theta: np.ndarray, fit: Fit, poses: PoseSet) -> np.ndarray:
    """(N,) sign of the term's offset at each pose, in its most varying component."""
    q, X = fit.problem.kinematics(fit.problem.split(fit.z)[0], poses.controls)[:2]
    parts = [term.control_offset(theta, poses, poses.controls.shape[1]), term.pose_offset(theta, poses, q, X),
             term.marker_offset(theta, poses).reshape(poses.n_poses, -1)]
    off = np.concatenate([np.nan_to_num(p) for p in parts], axis=1)
    return np.sign(off[:, int(np.argmax(np.var(off, axis=0)))])

def _params(term: ModelTerm, theta: np.ndarray, std: np.ndarray | None) -> dict[str, dict[str, Any]]:
    d = term.to_dict(theta, std)["parameters"]
    for v in d.values():
        if v["std"] is not None and not np.isfinite(v["std"]):
            v["std"] = None
    return d


def _evidence(f: Finding, poses: PoseSet, unit: str, folds: int) -> str:
    first = next(iter(f.parameters.items()), None)
    par = ""
    if first is not None:
        name, v = first
        scale = length_scale(unit) if v["unit"] == "m" else 1.0
        shown_unit = unit if v["unit"] == "m" else v["unit"]
        std = "" if v["std"] is None else f" +- {v['std'] / scale:.2g}"
        par = f"; fitted {name} = {v['value'] / scale:.3g}{std} {shown_unit}"
    return (f"adding {f.effect} ({_where_text(f.where)}) cut the {folds}-fold held-out RMS from "
            f"{_fmt_rms(f.heldout_rms_before, unit)} to {_fmt_rms(f.heldout_rms_after, unit)} over "
            f"{poses.n_poses} poses (paired Wilcoxon p = {f.p_heldout:.2g}, BIC {f.bic_change:+.0f}; "
            f"score test against the residual: Holm p = {f.p_screen:.2g}){par}")

def _finite_mean(a: np.ndarray, axis: int | None = None):
    """Mean of the finite entries (along ``axis``), NaN where there is none (a held-out pose or a
    marker the model could not predict), without numpy's warning about an empty mean."""
    ok = np.isfinite(a)
    n = ok.sum(axis=axis)
    total = np.where(ok, a, 0.0).sum(axis=axis)
    if axis is None:
        return float(total / n) if n else float("nan")
    return np.divide(total, n, out=np.full(np.shape(n), np.nan), where=n > 0)


def _score_heldout(base: Calibration, final: Calibration, heldout: PoseSet, spec: PlatformSpec,
                   findings: list[Finding], heldout_final: PoseSet | None = None,
                   windows: np.ndarray | None = None) -> dict[str, Any]:
    """diagnosis.json's ``heldout_session``: the point RMS (m) of the geometric model ``base`` and
    the diagnosed ``final`` on another recording, per marker, the paired one-sided p over its
    poses and ``n_poses``; each finding's ``heldout_session_rms_before/after`` set.
    ``heldout_final``: the recording as ``final`` reads it where that differs from ``heldout``
    (a stream's windows, each model's controls its own response's: platkit.diagnose.stream);
    ``windows``: each pose's window of a stream, for the paired test (stats.paired_improvement)."""
    e0 = point_errors(base, with_history(heldout, spec))
    e1 = point_errors(final, with_history(heldout if heldout_final is None else heldout_final, spec))
    before = float(np.sqrt(_finite_mean(e0**2)))
    after = float(np.sqrt(_finite_mean(e1**2)))
    for f in findings:
        f.heldout_session_rms_before, f.heldout_session_rms_after = before, after
    per_marker = {n: (float(np.sqrt(_finite_mean(e0[:, m] ** 2))), float(np.sqrt(_finite_mean(e1[:, m] ** 2))))
                  for m, n in enumerate(base.marker_names)}
    return {"rms_before": before, "rms_after": after, "per_marker": per_marker,
            "p_improvement": paired_improvement(_finite_mean(e0**2, axis=1), _finite_mean(e1**2, axis=1),
                                                windows),
            "n_poses": heldout.n_poses}
