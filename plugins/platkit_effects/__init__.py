"""platkit's built-in diagnosis effects, registered through ``platkit_register_effects`` exactly as
an outside package registers its own.

Each effect is an :class:`platkit.effects.Effect`; its terms are
:class:`platkit.terms.ModelTerm` subclasses whose ``theta`` the estimator fits with the
geometry. SI inside; a control offset is in the control's internal unit (m for 'm' controls,
rad, deg or counts otherwise). Time is measured from the session's first command.

| effect | term (one per actuator unless said) | theta |
|---|---|---|
| backlash | u_i + b d_i, d_i = sign of the actuator's last move | b: half the play |
| compliance | parallel stand (one term): u + c f, f = J^-T w, the actuator forces holding a 1 N weight at the moving frame's origin; URDF stand: q_j + c_j tau_j, tau = the whole tree's gravity torque at the joint's own deflected pose; a mimic joint on the chain: the moving frame turned about its axis by c tau; a URDF without inertias: q_j + Y_j(q) B theta, the mass moments' best-determined combinations | c; or theta (r <= 3) |
| link_bending | the links a joint carries turned at it about the axes across its axis by c M_across, M_across the part across the axis of the whole tree's gravity moment there (the moving frame where the joint carries every tracked link; the markers it carries where it carries only some, an arm's joint on a two-handed session) | c |
| thermal_drift | u_j + k h_j(t): every actuator longer by k times its heat h_j, the strokes it moved cooling with tau (150 s to 80 min, a factor sqrt(2) apart; one term, the physics); or u_j + a_j (1 - exp(-t / tau)), the warm-up with time since power-on (tau on the same grid); or X + v t, the moving frame translated linearly in time (the additive simulator's drift); the form chosen by the later part of the session held out | k; or a_j (one per actuator); or v (3) |
| cyclic_error | u_i + a sin(2 pi u_i / P) + b cos(2 pi u_i / P), P from a short list per unit | a, b |
| scale_nonlinearity | u_i + a P2(s) + b P3(s), s = travel scaled to [-1, 1] over the stroke (Legendre) | a, b |
| settling_lag | u - l (u_k - u_k-1): short of the command by a fraction of the last step (one term) | l |
| marker_slip | marker m moved by d (moving frame) from time t_s on (t_s: the marker's change point); a rigid body's three points each by its own step from one t_s (body_slip.py) | d (3); a body's 9 |
| base_tilt | the pose turned about the base x and y axes: X + w x X, R' = exp(w) R (one term) | w_x, w_y |

``where`` of every term holds what ``from_dict`` needs to rebuild it without the spec
(actuator name and index, unit, period, marker index, slip time, and for compliance the stand).
"""
from __future__ import annotations

from platkit.hookspecs import hookimpl
from platkit_effects.base_tilt import BaseTilt, BaseTiltTerm
from platkit_effects.body_slip import BodySlipTerm, MarkerOrBodySlip
from platkit_effects.compliance import (
    Compliance,
    ComplianceTerm,
    actuator_loads,
    cached_loads,
    parallel_actuator_forces,
    serial_gravity_torques,
)
from platkit_effects.drive import PERIODS, Backlash, BacklashTerm, CyclicError, CyclicTerm, ScaleNonlinearity, ScaleTerm
from platkit_effects.imu import IMU_EFFECTS
from platkit_effects.recording import (
    SLIP_DOMINANCE,
    MarkerSlip,
    MarkerSlipTerm,
    SettlingLag,
    SettlingTerm,
    change_point,
    one_marker_steps,
)
from platkit_effects.thermal import (
    COOLING_TAUS_S,
    ThermalDrift,
    ThermalDriftTerm,
    ThermalExpansionTerm,
    motion_heat,
    remember_heat,
)
from platkit_effects.tree_bending import LinkBending
from platkit_effects.tree_compliance import JointRotationTerm, MassMomentTerm

#: every name imported from platkit_effects (the effects live in one module per family: drive,
#: compliance, thermal, recording, base_tilt; their shared helpers in common)
__all__ = [
    "Backlash", "BacklashTerm", "BaseTilt", "BaseTiltTerm", "BodySlipTerm", "COOLING_TAUS_S", "Compliance", "ComplianceTerm",
    "CyclicError", "CyclicTerm", "EFFECTS", "JointRotationTerm", "LinkBending", "MassMomentTerm", "MarkerOrBodySlip", "MarkerSlip", "MarkerSlipTerm", "PERIODS", "SLIP_DOMINANCE",
    "ScaleNonlinearity", "ScaleTerm", "SettlingLag", "SettlingTerm", "ThermalDrift", "ThermalDriftTerm",
    "ThermalExpansionTerm", "actuator_loads", "cached_loads", "change_point", "motion_heat", "one_marker_steps",
    "parallel_actuator_forces", "platkit_register_effects", "remember_heat", "serial_gravity_torques",
]

EFFECTS = [Backlash(), Compliance(), ThermalDrift(), CyclicError(), ScaleNonlinearity(), SettlingLag(), MarkerOrBodySlip(),
           BaseTilt(), LinkBending()]


@hookimpl
def platkit_register_effects():
    return list(EFFECTS) + list(IMU_EFFECTS)
