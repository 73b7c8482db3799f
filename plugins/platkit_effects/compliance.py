"""compliance: the actuators give under the load they carry (a parallel stand's actuator forces
holding a weight at the moving frame; a URDF stand's gravity torques of the whole tree, every
control's joint at its command, mimic joints following their masters: see tree_compliance)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from platkit.effects import (
    CONTROL_SIZE_UNIT,
    Effect,
    SizeHelp,
    actuator_where,
    control_size,
    seen_controls,
    stored_actuator,
    stored_where,
)
from platkit.errors import BadInput
from platkit.kinematics import platform_model
from platkit.model import PlatformSpec
from platkit.plugins import get_platform
from platkit.terms import ModelTerm
from platkit.tree_loads import tree_loads
from platkit_effects.physics import CompliancePhysics
from platkit_effects.tree_compliance import (
    JointRotationTerm,
    MassMomentTerm,
    _stand_where,
    deflected_torque,
    joint_rotation_from_dict,
    joint_rotation_term,
    load_state,
    loaded_controls,
    mass_moment_basis,
    mass_moment_from_dict,
    mass_moment_term,
    tree_stand,
    untried_compliance,
    urdf_of,
)
from platkit_effects.tree_joints import JointsComplianceTerm, joints_compliance_from_dict, joints_compliance_term


def serial_gravity_torques(urdf: str, joints: tuple[str, ...], q: np.ndarray) -> np.ndarray:
    """(N, n) gravity torques (N m; N for prismatic joints) of ``joints`` at joint values q (N, n)
    (rad, m), from the URDF's inertias: the whole tree's loads (platkit.tree_loads), the joints not
    given at zero, mimic joints following their masters, gravity -z. Joints named otherwise (like
    the rotary's u1, u2) take the URDF's one-dof joints in order."""
    T = tree_loads(urdf)
    names = list(joints)
    if not all(n in T.recorded for n in names):
        if len(T.recorded) < len(names):
            raise BadInput(f"{urdf}: cannot match the controls {', '.join(joints)} to the URDF's joints")
        names = T.recorded[: len(names)]
    tau = T.loads(T.configuration(names, np.atleast_2d(q))).torque
    return tau[:, [T.index[n] for n in names]]


def parallel_actuator_forces(spec: PlatformSpec, controls: np.ndarray) -> np.ndarray:
    """(N, n_u) actuator forces f = J^-T w holding a 1 N weight (gravity along base -z) at the
    moving frame's origin, at the nominal geometry: from F_u du + F_p dp = 0, J = du/dp, and
    virtual work J^T f = dz/dp. Unit: N per N of payload weight (counts, rad: per unit)."""
    import casadi as ca

    model = platform_model(spec)
    fk = model.forward_batch(controls, strict=False)
    p = ca.SX.sym("p", spec.n_p)
    _, X = spec.pose(p)
    dz_dp = ca.Function("dz_dp", [p], [ca.jacobian(X[2], p)])
    td = spec.nominal_td()
    out = np.zeros_like(np.atleast_2d(controls), dtype=float)
    for k, (u, pk) in enumerate(zip(np.atleast_2d(controls), fk.p)):
        _, F_p, F_u, _ = model.F_jac(u, td, pk)
        du_dp = -np.linalg.lstsq(np.asarray(F_u), np.asarray(F_p), rcond=None)[0]
        out[k] = np.linalg.lstsq(du_dp.T, np.asarray(dz_dp(pk)).ravel(), rcond=None)[0]
    return out


def actuator_loads(spec: PlatformSpec, controls: np.ndarray) -> np.ndarray:
    """(N, n_u) the load each actuator carries: gravity torques from the URDF for serial chains,
    J^-T w for a unit payload weight otherwise (see the two functions above)."""
    controls = np.atleast_2d(np.asarray(controls, float))
    stand = tree_stand(spec)
    if stand is not None:
        S = load_state(stand, controls)
        return S.loads.torque[:, [stand.loads.index[n] for n in stand.joints]]
    return parallel_actuator_forces(spec, controls)


_LOADS: dict[tuple, np.ndarray] = {}


def cached_loads(spec: PlatformSpec, controls: np.ndarray) -> np.ndarray:
    """actuator_loads, once per (stand, payload, controls array): terms ask for them at every evaluation."""
    chain = spec.extras.get("chain")
    key = (spec.name, str(spec.description_path), tuple(spec.control_names), getattr(chain, "base_link", None),
           getattr(chain, "moving_link", None), tuple(spec.tracked_links), tuple(spec.extras.get("payload") or ()),
           np.ascontiguousarray(controls, float).tobytes())
    if key not in _LOADS:
        if len(_LOADS) > 256:
            _LOADS.clear()
        _LOADS[key] = actuator_loads(spec, controls)
    return _LOADS[key]


@dataclass
class ComplianceTerm(ModelTerm):
    index: int | None = None  # None: one compliance for every actuator (parallel stands)
    spec: PlatformSpec | None = field(default=None, repr=False)

    def stand(self) -> PlatformSpec:
        if self.spec is None:

            w = self.where
            self.spec = get_platform(w["platform"], w.get("description"), **(w.get("platform_options") or {}))
        return self.spec

    def control_offset(self, theta, poses, n_u):
        """``c`` times the load; on a URDF stand the joint's load at its own deflected
        configuration (the fixed point of tree_compliance.deflected_torque)."""
        spec = self.stand()
        out = np.zeros((poses.n_poses, n_u))
        if self.index is None:
            out[:] = theta[0] * cached_loads(spec, poses.controls)
            return out
        stand = tree_stand(spec)
        if stand is None:
            out[:, self.index] = theta[0] * cached_loads(spec, poses.controls)[:, self.index]
            return out
        i = self.index
        out[:, i] = theta[0] * deflected_torque(stand, poses.controls, stand.joints[i], theta[0] * stand.scale[i])
        return out


class Compliance(Effect):
    name = "compliance"
    summary = "deflection that grows with the load an actuator or joint carries"
    simulation_size = SizeHelp("the largest deflection of an actuator over the commands", CONTROL_SIZE_UNIT)
    physics_size = simulation_size

    def term(self, spec, i):
        if i is None:
            unit = spec.controls[0].unit
            where = {"actuator": "all", "unit": unit, "load": "actuator force J^-T w for a 1 N payload weight"}
            where.update(_stand_where(spec))
            return ComplianceTerm(self.name, ["deflection_per_newton_payload"], np.zeros(1), [f"{unit}/N"], where,
                                  index=None, spec=spec)
        where = actuator_where(spec, i)
        load_unit = "N" if spec.controls[i].unit == "m" else "N m"
        stand = tree_stand(spec)
        source = "the prior of uniform links (the URDF has no inertias)" if stand is not None and stand.loads.prior \
            else "the URDF inertias"
        where.update({"load": f"gravity torque from {source} ({load_unit})"})
        where.update(_stand_where(spec))
        return ComplianceTerm(self.name, ["compliance"], np.zeros(1), [f"{where['unit']}/({load_unit})"], where,
                              index=i, spec=spec)

    def candidates(self, spec, poses, residuals=None):
        stand = tree_stand(spec)
        if stand is None:
            loads = cached_loads(spec, poses.controls)
            return [self.term(spec, None)] if np.ptp(loads) > 0 else []
        terms: list = []
        if stand.loads.prior:  # no inertias: beside the prior's loads, through each joint's mass moments
            for i, joint in enumerate(stand.joints):
                basis, rank = mass_moment_basis(stand, poses.controls, joint)
                if basis.shape[1]:
                    terms.append(mass_moment_term(self.name, spec, i, joint, basis, rank))
        S = load_state(stand, poses.controls)
        tau = S.loads.torque
        loaded = loaded_controls(stand, poses.controls)
        terms += [self.term(spec, i) for i in loaded]
        terms += [joint_rotation_term(self.name, spec, n, "axis") for n in stand.shared
                  if n in stand.loads.mimic and np.ptp(tau[:, stand.loads.index[n]]) > 1e-9]
        seen = loaded_controls(stand, poses.controls, seen=True)
        if len(seen) > 1 and len(stand.tracked) > 1:  # a tree gives at many joints at once: every loaded joint, one term
            terms.append(joints_compliance_term(self.name, spec, seen))
        return terms

    def untried(self, spec, poses):
        """Why compliance is not tried at some joints of a URDF stand (see untried_compliance)."""
        return untried_compliance(spec, poses)

    def regressor(self, term, spec, poses):
        if isinstance(term, JointsComplianceTerm):  # the joint whose load varies most
            tau = actuator_loads(spec, poses.controls)[:, term.indices]
            return tau[:, int(np.argmax(np.ptp(tau, axis=0)))]
        if isinstance(term, MassMomentTerm):
            return term.columns(poses.controls)[:, 0]
        if isinstance(term, JointRotationTerm):
            stand = tree_stand(spec)
            if stand is None:
                return np.zeros(poses.n_poses)
            return load_state(stand, poses.controls).loads.torque[:, stand.loads.index[term.joint]]
        loads = cached_loads(spec, poses.controls)
        return loads[:, term.index] if term.index is not None else loads @ np.sign(np.mean(loads, axis=0))

    def regressor_label(self, term):
        if isinstance(term, JointsComplianceTerm):
            return "gravity torque on the joint whose load varies most (N m)"
        if isinstance(term, MassMomentTerm):
            return f"gravity torque on {term.where['actuator']} per its best-determined mass-moment combination (N m)"
        if isinstance(term, JointRotationTerm):
            return f"gravity torque on joint {term.joint} (N m)"
        if term.index is None:
            return "sum of the actuator forces for a 1 N payload (N/N)"
        return f"gravity load on {term.where['actuator']} ({term.where['load'].split('(')[-1].rstrip(')')})"

    def from_dict(self, data, spec=None):
        where = stored_where(data)
        if "actuator_indices" in where:
            return joints_compliance_from_dict(self.name, data, spec)
        if "basis" in where:
            return mass_moment_from_dict(self.name, data, spec)
        if "about" in where:
            return joint_rotation_from_dict(self.name, data, spec)
        if spec is None:

            if not isinstance(where.get("platform"), str):
                raise BadInput("effect 'compliance': where.platform must name the stand the loads come from")
            spec = get_platform(where["platform"], where.get("description"), **(where.get("platform_options") or {}))
        if where.get("actuator") == "all":
            return self.term(spec, None)
        i, _, _ = stored_actuator(spec, data, self.name)
        return self.term(spec, i)

    def simulation_term(self, spec, size, rng, commands):
        """``size``: the largest deflection of an actuator over the commands (mm for lengths)."""
        loads = cached_loads(spec, commands.controls)
        if urdf_of(spec) is None:
            term = self.term(spec, None)
            j = int(np.argmax(np.max(np.abs(loads), axis=0)))
        else:
            j = _loaded_control(spec, loads, rng)
            term = self.term(spec, j)
        peak = float(np.max(np.abs(loads[:, j])))
        if not peak > 0:
            raise BadInput(f"effect compliance: the {spec.name} stand carries no load on its actuators")
        return term, np.array([control_size(spec, j, size, 1.0) / peak])

    def physics(self, spec, size, rng, plan):
        """``size``: the largest deflection of an actuator over the commands (mm for lengths)."""
        loads = cached_loads(spec, plan.commands)
        start = actuator_loads(spec, plan.start[None])[0]
        if urdf_of(spec) is None:
            j, index, where = int(np.argmax(np.max(np.abs(loads), axis=0))), None, {"actuator": "all"}
        else:
            j = _loaded_control(spec, loads, rng)
            index, where = j, {"actuator": spec.control_names[j]}
        peak = float(np.max(np.abs(loads[:, j])))
        if not peak > 0:
            raise BadInput(f"effect compliance: the {spec.name} stand carries no load on its actuators")
        return CompliancePhysics(control_size(spec, j, size, 1.0) / peak, loads, start, index, spec.controls[j].unit, where)


def _loaded_control(spec: PlatformSpec, loads: np.ndarray, rng: np.random.Generator) -> int:
    """The joint a simulated compliance is planted at: drawn among those whose load varies over the
    commands at least half as much as the most varied one's; where the joint drawn moves no tracked
    link (a tree's head or untracked leg: no marker could show its deflection), drawn again the
    same way among the joints that move one."""
    span = np.ptp(loads, axis=0)
    j = int(rng.choice(np.nonzero(span >= 0.5 * span.max())[0]))
    seen = seen_controls(spec)
    if seen[j]:
        return j
    if not np.any(seen & (span > 0)):
        raise BadInput(f"effect compliance: no joint of {spec.name} that moves a tracked link carries a varying load")
    span = np.where(seen, span, 0.0)
    return int(rng.choice(np.nonzero(span >= 0.5 * span.max())[0]))
