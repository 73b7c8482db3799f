"""The model's frames: how far the parameters a calibration held at nominal can turn them.

The calibration fixes the model's base and platform frames only up to the parameters it holds at
nominal (its gauge: the motion capture cannot see them). A real stand whose held parameters
differ from the description turns the model's base frame against the real base (an
accelerometer sees that as a tilt) and its platform frame against the real platform (a gyro sees
that as a misalignment). :func:`frame_gauge` computes how far, from the forward kinematics, for
held parameters off by a typical error (``HELD_PARAMETER_STD``); the IMU effects' own
``frame_covariance`` turns that into an allowance in their parameters, which enters the Wald
tests and the findings' stds.
"""
from __future__ import annotations

import numpy as np

from platkit.calibrate.plan import stand_length_scale
from platkit.geometry import matrix_from_quat, rotvec_from_matrix, skew
from platkit.kinematics import PlatformModel

#: how far a real stand's held parameters are taken to differ from its description (1 sigma),
#: by unit; other units: this share of the nominal value. A real stand differs from its
#: description by a few mm (docs/stands.md); platkit.simulate draws its true stands the same way.
HELD_PARAMETER_STD = {"m": 2e-3, "rad": 2e-3}
HELD_PARAMETER_RELATIVE_STD = 1e-3


def held_parameter_std(spec) -> np.ndarray:
    """(n_td,) how far each parameter of a real stand is taken to be from its description."""
    out = np.empty(spec.n_td)
    for i, p in enumerate(spec.parameters):
        sd = HELD_PARAMETER_STD.get(p.unit)
        out[i] = sd if sd is not None else HELD_PARAMETER_RELATIVE_STD * (abs(p.nominal) if p.nominal != 0 else 1.0)
    return out


def frame_gauge(spec, td, U: np.ndarray, td_status, model=None) -> tuple[np.ndarray, np.ndarray, int]:
    """How far the parameters a calibration held at nominal can turn the model's frames.

    A held parameter's error is invisible to the motion capture: the estimated parameters, the
    mocap transform (a rigid motion of the base) and the marker positions (a rigid motion of the
    platform) take it. From forward kinematics at the command rows ``U`` (N, n_u, SI) the held
    parameter's effect on the poses is split (least squares) into the estimated parameters'
    effects and the two rigid motions; the rotation parts b_j (base frame axes) and p_j (platform
    axes) are how far the model's base and platform frames turn per unit of parameter j. With
    the errors of :func:`held_parameter_std`, independent: C_base = sum s_j^2 b_j b_j^T and
    C_platform alike. Returns (C_base (3, 3), C_platform (3, 3)) rad^2 and the number of held
    parameters (0: both zero)."""

    status = list(td_status)
    held = [i for i, s in enumerate(status) if s == "held_at_nominal"]
    if not held:
        return np.zeros((3, 3)), np.zeros((3, 3)), 0
    free = [i for i, s in enumerate(status) if s == "estimated"]
    model = model or PlatformModel(spec)
    td = np.asarray(td, float)
    U = np.atleast_2d(np.asarray(U, float))
    fb = model.forward_batch(U, td=td, strict=False)
    ok = fb.converged
    R0, X0 = matrix_from_quat(fb.q[ok]), fb.X[ok]
    K = len(X0)
    L = stand_length_scale(spec)

    def effect(i: int) -> np.ndarray:
        """(K, 6): rotation (base axes, times L) and translation of the poses per unit of td_i."""
        hstep = 1e-5 * max(1.0, abs(td[i])) if spec.parameters[i].unit not in ("m", "rad") else 1e-5
        d = np.zeros_like(td)
        d[i] = hstep
        a = model.forward_batch(U[ok], td=td + d, strict=False)
        b = model.forward_batch(U[ok], td=td - d, strict=False)
        rot = rotvec_from_matrix(matrix_from_quat(a.q) @ np.transpose(matrix_from_quat(b.q), (0, 2, 1))) / (2 * hstep)
        return np.concatenate([L * rot, (a.X - b.X) / (2 * hstep)], axis=1)

    eye = np.broadcast_to(np.eye(3), (K, 3, 3))
    zero = np.zeros((K, 3, 3))
    rigid = np.concatenate([
        np.concatenate([L * eye, -skew(X0)], axis=1),  # base rotation b: X -> X + b x X
        np.concatenate([zero, eye], axis=1),  # base translation
        np.concatenate([L * R0, zero], axis=1),  # platform rotation p (platform axes)
        np.concatenate([zero, R0], axis=1),  # platform translation
    ], axis=2)  # (K, 6, 12)
    A = np.concatenate([np.stack([effect(i) for i in free], axis=2) if free else np.zeros((K, 6, 0)), rigid], axis=2)
    A = A.reshape(-1, A.shape[2])
    nf = len(free)
    sd = held_parameter_std(spec)
    C_b, C_p = np.zeros((3, 3)), np.zeros((3, 3))
    for j in held:
        x = np.linalg.lstsq(A, effect(j).reshape(-1), rcond=1e-12)[0]
        b, p = x[nf:nf + 3] * sd[j], x[nf + 6:nf + 9] * sd[j]
        C_b += np.outer(b, b)
        C_p += np.outer(p, p)
    return C_b, C_p, len(held)
