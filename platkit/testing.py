"""The conformance suite every stand passes, built-in or third-party.

    from platkit.testing import check_platform
    check_platform(spec)          # raises AssertionError naming the failed check
    check_effect(effect, spec)    # the same for a diagnosis effect (platkit.effects.Effect) on a stand
    check_imu_effect(effect)      # an IMU effect (platkit.effects.ImuEffect)

Checks: the spec validates; a stand with more residual rows than pose coordinates declares its
rows' plausible misfit, and a declared free pose space is free; F = 0 at the neutral pose; CasADi
Jacobians of F against central finite differences; inverse-then-forward round trips at random poses near neutral; forward-then-
inverse round trips at random controls; the closed-form inverse (if any) against the iterative one.
"""
from __future__ import annotations

import numpy as np

from platkit.effects import Effect, EffectPhysics, ImuEffect, PhysicsPlan, SizeHelp, theta_from_dict, with_history
from platkit.errors import PlatkitError
from platkit.kinematics import PlatformModel
from platkit.kinematics.sampling import controls_of_poses, pose_box
from platkit.model import PlatformSpec, validate_spec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm


def _fd_jacobian(f, x, h):
    x = np.asarray(x, float)
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = h[i] if np.ndim(h) else h
        cols.append((f(x + e) - f(x - e)) / (2 * e[i]))
    return np.stack(cols, axis=1)


def _random_controls(spec: PlatformSpec, model: PlatformModel, rng, n: int) -> list[np.ndarray]:
    """Controls of random reachable poses: perturb the neutral controls within 8% of each stroke,
    or, for a stand whose pose space is free, the neutral pose within 8% of each coordinate's
    range, mapped through inverse kinematics (independent controls of such a stand are
    inconsistent)."""
    if spec.pose_free:
        return [u for u in _random_pose_controls(spec, model, rng, n)[1]]
    lo, hi = spec.control_bounds()
    u0 = spec.neutral_u()
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    out = []
    for _ in range(n):
        u = np.clip(u0 + rng.uniform(-0.08, 0.08, spec.n_u) * span, lo, hi)
        out.append(u)
    return out


def _random_pose_controls(spec: PlatformSpec, model: PlatformModel, rng, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(P (n, n_p), U (n, n_u)): poses within 8% of each coordinate's range of the neutral pose
    that the stand takes, with their controls."""
    lo, hi = pose_box(spec)
    p0 = spec.neutral_p()
    P_all, U_all = [], []
    for _ in range(20):
        P = np.clip(p0 + rng.uniform(-0.08, 0.08, (2 * n, spec.n_p)) * (hi - lo), lo, hi)
        res = controls_of_poses(model, P)
        P_all += list(P[res["ok"]])
        U_all += list(res["controls"][res["ok"]])
        if len(P_all) >= n:
            break
    assert len(P_all) >= n, f"{spec.name}: fewer than {n} poses near neutral have controls inside the strokes on the branch"
    return np.array(P_all[:n]), np.array(U_all[:n])


def _check_declarations(spec: PlatformSpec, model: PlatformModel, rng) -> dict:
    """A stand with more residual rows than pose coordinates declares its rows' plausible misfit;
    the declared free space is free: most samples of it are taken by the stand."""
    where = f"{spec.description_path}: " if spec.description_path is not None else ""
    if model.n_r > spec.n_p:
        assert spec.misfit is not None, (
            f"{where}stand {spec.name!r}: {model.n_r} residual rows for {spec.n_p} pose coordinates and no plausible "
            f"misfit declared (field 'misfit': one platkit.model.RowMisfit per row)")
    out: dict = {"free_space": spec.free_space}
    if spec.pose_free:
        lo, hi = pose_box(spec, 0.1)
        P = rng.uniform(lo, hi, (40, spec.n_p))
        ok = controls_of_poses(model, P)["ok"]
        out["free_space_taken"] = float(ok.mean())
        assert ok.mean() >= 0.5, (
            f"{where}stand {spec.name!r}: field 'free_space' is 'pose' but only {int(ok.sum())} of 40 poses drawn in "
            f"the coordinates' bounds have controls inside the strokes on the branch")
    return out


def check_platform(spec: PlatformSpec, n_samples: int = 20, seed: int = 0, tol_pose: float = 1e-8) -> dict:
    """Run the conformance checks on ``spec``; return a dict of figures; AssertionError on failure."""
    rng = np.random.default_rng(seed)
    validate_spec(spec)
    model = PlatformModel(spec)
    td = spec.nominal_td()
    report: dict = {"platform": spec.name}
    report.update(_check_declarations(spec, model, rng))

    # 1. neutral pose satisfies the constraints under neutral controls
    r0 = model.residual(spec.neutral_u(), spec.neutral_p(), td)
    assert np.linalg.norm(r0) < 1e-6, f"{spec.name}: |F| = {np.linalg.norm(r0):.3g} at the neutral pose and neutral controls"

    # 2. Jacobians against finite differences at random points near neutral
    worst = 0.0
    for u in _random_controls(spec, model, rng, 3):
        p = spec.neutral_p() + rng.normal(0, 1e-3, spec.n_p)
        r, Jp, Ju, Jtd = (np.asarray(a) for a in model.F_jac(u, td, p))
        for J, f, x in (
            (Jp, lambda x: model.residual(u, x, td), p),
            (Ju, lambda x: model.residual(x, p, td), u),
            (Jtd, lambda x: model.residual(u, p, x), td),
        ):
            h = 1e-6 * np.maximum(1.0, np.abs(x))
            Jfd = _fd_jacobian(f, x, h)
            err = np.max(np.abs(J - Jfd)) / max(1.0, np.max(np.abs(Jfd)))
            worst = max(worst, err)
            assert err < 1e-5, f"{spec.name}: CasADi Jacobian differs from finite differences by {err:.3g}"
    report["jacobian_fd_error"] = worst

    # 3. forward then inverse, and inverse then forward, round trips
    worst_u = worst_pose = 0.0
    # control errors are judged relative to each control's stroke (units differ: m, rad, counts)
    lo, hi = spec.control_bounds()
    span = np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, 1.0)
    n_ok = 0
    for u in _random_controls(spec, model, rng, n_samples):
        try:
            fk = model.forward(u, td)
        except PlatkitError as exc:
            raise AssertionError(f"{spec.name}: forward kinematics failed at u={u.tolist()}: {exc}") from None
        assert fk.on_branch, f"{spec.name}: forward kinematics from neutral left the stand's branch at u={u.tolist()}"
        r = np.asarray(spec.residual(u, td, fk.q, fk.X)).ravel()
        assert np.linalg.norm(r) < 1e-8, f"{spec.name}: |F| = {np.linalg.norm(r):.3g} at a forward solution"
        # from neutral controls, not the answer: the iterative route must find its own way
        u_back = model.inverse(fk.q, fk.X, td, strict=False)
        # redundant stands may return another u for the same pose: compare poses then
        fk2 = model.forward(u_back, td, guess=fk.p if np.all(np.isfinite(fk.p)) else None, strict=False)
        worst_pose = max(worst_pose, np.linalg.norm(fk2.X - fk.X), 1 - abs(float(np.dot(fk2.q, fk.q))))
        if spec.n_u <= spec.n_p:
            worst_u = max(worst_u, float(np.max(np.abs(u_back - u) / span)))
        n_ok += 1
    assert worst_pose < tol_pose, f"{spec.name}: forward/inverse round trip misses the pose by {worst_pose:.3g}"
    assert worst_u < 1e-8, f"{spec.name}: forward/inverse round trip misses the controls by {worst_u:.3g} of a stroke"
    report.update(round_trips=n_ok, round_trip_pose_error=worst_pose, round_trip_control_error=worst_u)

    # 4. closed-form inverse agrees with the generic Newton route
    if spec.inverse is not None:
        u = _random_controls(spec, model, rng, 1)[0]
        fk = model.forward(u, td)
        u_newton = model._inverse_newton(fk.q, fk.X, td, spec.neutral_u())
        err = float(np.max(np.abs(u_newton - u) / span))
        assert err < 1e-8, f"{spec.name}: closed-form and Newton inverse kinematics differ by {err:.3g} of a stroke"
        report["closed_form_vs_newton"] = err

    # 5. velocity and acceleration kinematics against finite differences of forward kinematics
    #    along the control path u(t) = u + t u' + t^2 u''/2
    worst_v = worst_a = 0.0
    for u in _random_controls(spec, model, rng, 3):
        fk = model.forward(u, td)
        if spec.pose_free:
            # consistent rates: a pose-free stand's independent control rates fit no motion
            scale = pose_box(spec)[1] - pose_box(spec)[0]
            udot, uddot = model.inverse_acceleration(fk.p, rng.normal(0, 0.02, spec.n_p) * scale,
                                                     rng.normal(0, 0.02, spec.n_p) * scale, td, u=u)
        else:
            udot = rng.normal(0, 0.02, spec.n_u) * span
            uddot = rng.normal(0, 0.02, spec.n_u) * span
        pdot, pddot = model.forward_acceleration(u, udot, uddot, td, p=fk.p)
        pdot_only = model.forward_velocity(u, udot, td, p=fk.p)
        h = 1e-4

        def p_at(t):
            return model.forward(u + t * udot + 0.5 * t * t * uddot, td, guess=fk.p, strict=False).p

        p_plus, p_minus = p_at(h), p_at(-h)
        fd_v = (p_plus - p_minus) / (2 * h)
        fd_a = (p_plus - 2 * fk.p + p_minus) / h**2
        scale_v = max(1.0, float(np.max(np.abs(fd_v))))
        scale_a = max(1.0, float(np.max(np.abs(fd_a))))
        worst_v = max(worst_v, float(np.max(np.abs(pdot - fd_v))) / scale_v, float(np.max(np.abs(pdot_only - fd_v))) / scale_v)
        worst_a = max(worst_a, float(np.max(np.abs(pddot - fd_a))) / scale_a)
        # and back: the inverse rate solution reproduces the control rates where u is determined
        if spec.n_u <= spec.n_p:
            udot_back, uddot_back = model.inverse_acceleration(fk.p, pdot, pddot, td, u=u)
            worst_v = max(worst_v, float(np.max(np.abs(udot_back - udot) / span)))
            worst_a = max(worst_a, float(np.max(np.abs(uddot_back - uddot) / span)))
    assert worst_v < 1e-6, f"{spec.name}: velocity kinematics differ from finite differences by {worst_v:.3g}"
    assert worst_a < 1e-4, f"{spec.name}: acceleration kinematics differ from finite differences by {worst_a:.3g}"
    report.update(velocity_fd_error=worst_v, acceleration_fd_error=worst_a)
    return report


def check_imu_effect(effect, seed: int = 0) -> dict:
    """The conformance checks of an IMU effect (:class:`platkit.effects.ImuEffect`), built-in or
    outside: what the simulator and the diagnosis rely on. Returns a dict of figures;
    AssertionError naming the effect and the check on failure.

    Checks: its name, sensor, parameter names, display scale and floor; theta = 0 is no effect
    (the diagnosis nests every model in the one without it); the sensor model's outputs have the
    documented shapes and are finite, its rotations are rotations; its reports, size and
    calibration entry are what a finding and calibration.yaml take.
    """
    name = getattr(effect, "name", None)
    assert isinstance(effect, ImuEffect), f"{effect!r}: not a platkit.effects.ImuEffect"
    assert isinstance(name, str) and name, f"{effect!r}: an IMU effect needs a name"
    assert effect.sensor in ("gyro", "accelerometer"), f"{name}: sensor {effect.sensor!r}, expected gyro or accelerometer"
    n = effect.n_params
    assert n > 0 and all(isinstance(p, str) and p for p in effect.parameter_names), \
        f"{name}: parameter_names must name each parameter"
    assert effect.display_scale > 0 and effect.min_size >= 0 and effect.min_separability >= 0, \
        f"{name}: display_scale must be positive, min_size and min_separability 0 or more"
    rng = np.random.default_rng(seed)
    t = np.linspace(-60.0, 60.0, 11)
    zero = np.zeros(n)
    for label, out, shape in (("gyro_bias", effect.gyro_bias(zero, t), (len(t), 3)),
                              ("accelerometer_bias", effect.accelerometer_bias(zero, t), (len(t), 3)),
                              ("sensor_from_platform", effect.sensor_from_platform(zero), (3, 3)),
                              ("level_from_base", effect.level_from_base(zero), (3, 3))):
        out = np.asarray(out, float)
        assert out.shape == shape, f"{name}: {label} has shape {out.shape}, expected {shape}"
        expected = np.eye(3) if shape == (3, 3) else np.zeros(shape)
        assert np.allclose(out, expected, atol=1e-12), f"{name}: {label} at theta = 0 is not 'no effect'"
    size = 3.0 * max(effect.min_size, 1e-3)
    theta = effect.simulation_theta(size, rng)
    assert np.shape(theta) == (n,) and np.all(np.isfinite(theta)), f"{name}: simulation_theta gives {theta!r}"
    assert abs(effect.size(theta) - size) <= 1e-6 * size, \
        f"{name}: size(simulation_theta({size:g})) = {effect.size(theta):.6g}, expected {size:g}"
    for label in ("gyro_bias", "accelerometer_bias"):
        out = np.asarray(getattr(effect, label)(theta, t), float)
        assert out.shape == (len(t), 3) and np.all(np.isfinite(out)), f"{name}: {label} is not (N, 3) finite numbers"
    for label in ("sensor_from_platform", "level_from_base"):
        R = np.asarray(getattr(effect, label)(theta), float)
        assert R.shape == (3, 3) and np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0, \
            f"{name}: {label} is not a rotation matrix"
    C = np.asarray(effect.frame_covariance(theta, np.eye(3) * 1e-6, np.eye(3) * 1e-6), float)
    assert C.shape == (n, n) and np.allclose(C, C.T) and np.all(np.linalg.eigvalsh(C) > -1e-15), \
        f"{name}: frame_covariance must be a symmetric ({n}, {n}) covariance"
    cov = np.eye(n) * (0.1 * float(np.max(np.abs(theta))) + 1e-12) ** 2
    context = {"sensor": effect.sensor, "n": 40, "span_s": (0.0, 200.0), "t_ref": 100.0, "b0": np.zeros(3),
               "b0_std": np.zeros(3), "heldout_before": 2.0, "heldout_after": 1.0,
               "heldout_unit": "deg/s" if effect.sensor == "gyro" else "m/s^2", "p_heldout": 1e-4, "p_screen": 1e-5,
               "separability": 0.5}
    rep = effect.report(theta, cov, context)
    assert isinstance(rep, dict) and {"parameters", "where", "evidence"} <= set(rep), \
        f"{name}: report must give parameters, where and evidence"
    for pname, p in rep["parameters"].items():
        assert {"value", "std", "unit"} <= set(p) and np.isfinite(p["value"]) and p["std"] >= 0, \
            f"{name}: report's parameter {pname!r} needs a finite value, a std and a unit"
    assert isinstance(rep["evidence"], str) and rep["evidence"], f"{name}: report's evidence must be a sentence"
    entry = effect.calibration_entry(theta, cov, context)
    assert isinstance(entry, dict) and entry, f"{name}: calibration_entry must give a mapping for calibration.yaml"
    assert isinstance(effect.headline(rep["parameters"]), str), f"{name}: headline must be a few words"
    assert effect.candidates(None, None) == [], f"{name}: an IMU effect adds no motion-capture term"
    return {"effect": name, "sensor": effect.sensor, "n_params": n, "reported_as": effect.finding_name}


def _effect_session(spec: PlatformSpec, rng, n: int = 24, n_markers: int = 3):
    """A small session for :func:`check_effect`: random commands within 30% of each stroke about
    neutral, 2 s apart, markers at zero, the history filled in; and residuals (N, M, 3) m with the
    first marker stepping by 1 mm halfway (so that effects located in the residuals find something)."""
    lo, hi = spec.control_bounds()
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    U = np.clip(spec.neutral_u() + rng.uniform(-0.3, 0.3, (n, spec.n_u)) * span, lo, hi)
    poses = with_history(PoseSet(spec.name, U, np.zeros((n, n_markers, 3)), [f"m{k + 1}" for k in range(n_markers)],
                                 t=2.0 * np.arange(n, dtype=float)), spec)
    residuals = 1e-5 * rng.normal(size=(n, n_markers, 3))
    residuals[n // 2:, 0] += np.array([1e-3, -5e-4, 2e-4])
    return poses, residuals


def _check_term(effect: Effect, term: ModelTerm, spec: PlatformSpec, poses: PoseSet, theta: np.ndarray | None,
                rng) -> None:
    """One term of ``effect``: its fields, its offsets (shapes, finite, nothing at theta = 0), its
    stored form back through ``from_dict``, its regressor, and what a recording artefact says."""
    name = effect.name
    label = f"{name} term {term.where!r}"
    assert isinstance(term, ModelTerm), f"{name}: a term must be a platkit.terms.ModelTerm, got {type(term).__name__}"
    assert term.effect == name, f"{label}: its effect is {term.effect!r}, not the effect's name"
    k = len(term.parameter_names)
    assert k > 0 and len(np.atleast_1d(term.initial)) == k and (not term.units or len(term.units) == k), \
        f"{label}: parameter_names, initial and units must have one entry per parameter"
    assert isinstance(term.where, dict), f"{label}: where must be a mapping"
    N, n_u, M = poses.n_poses, spec.n_u, poses.n_markers
    model = PlatformModel(spec)
    fk = model.forward_batch(poses.controls, strict=False)
    theta = 1e-3 * rng.normal(size=k) if theta is None else np.asarray(theta, float)
    for th, zero in ((np.zeros(k), True), (theta, False)):
        for what, out, shape in (("control_offset", term.control_offset(th, poses, n_u), (N, n_u)),
                                 ("pose_offset", term.pose_offset(th, poses, fk.q, fk.X), (N, 6)),
                                 ("marker_offset", term.marker_offset(th, poses), (N, M, 3))):
            out = np.asarray(out, float)
            assert out.shape == shape, f"{label}: {what} has shape {out.shape}, expected {shape}"
            assert np.all(np.isfinite(out)), f"{label}: {what} is not finite"
            if zero:
                assert np.allclose(out, 0.0, atol=1e-15), f"{label}: {what} at theta = 0 is not 'no effect'"
    stored = term.to_dict(theta, np.abs(theta))
    back = effect.from_dict(stored, spec)
    assert isinstance(back, ModelTerm) and back.effect == name and list(back.parameter_names) == list(term.parameter_names), \
        f"{label}: from_dict(to_dict(...)) does not give the term back"
    assert np.allclose(theta_from_dict(stored, back.parameter_names), theta), f"{label}: theta does not survive to_dict"
    reg = np.asarray(effect.regressor(term, spec, poses), float)
    assert reg.shape == (N,), f"{label}: regressor has shape {reg.shape}, expected ({N},)"
    assert isinstance(effect.regressor_label(term), str) and effect.regressor_label(term), \
        f"{label}: regressor_label must be a label"
    if effect.recording:
        onset = effect.onset(term)
        assert onset is None or np.isfinite(float(onset)), f"{label}: onset must be a time in s or None"
        for moved in effect.moved_markers(term, theta, np.abs(theta)):  # moved_marker's by default
            m, offset, sd = moved
            assert isinstance(m, (int, np.integer)) and 0 <= m < M, f"{label}: moved_markers' index {m!r} is no marker"
            assert np.shape(offset) == (3,) and np.shape(sd) == (3,), f"{label}: moved_markers' offset and std are (3,)"
        for unwritten in (None, "0.1 mm against 0.1 mm (paired p = 0.5), not 2% better"):
            text = effect.correction(term.where, unwritten)
            assert isinstance(text, str) and text, f"{label}: correction must be a sentence"


def check_effect(effect, spec: PlatformSpec, seed: int = 0) -> dict:
    """The conformance checks of a diagnosis effect (:class:`platkit.effects.Effect`), built-in or
    outside, on the stand ``spec``: what diagnosis, calibration.yaml and the simulators rely on.
    An IMU effect (:class:`platkit.effects.ImuEffect`) gets :func:`check_imu_effect`. Returns a
    dict of figures; AssertionError naming the effect and the check on failure.

    Checks: its name and summary; the attributes the core reads (``recording``, ``direction``,
    ``unsettled_holds`` flags, an ``unsettled_holds`` effect being a recording artefact,
    ``not_separable_advice`` a string, ``size_help`` a :class:`SizeHelp` or None in each
    simulator, and given where ``simulation_term`` / ``physics`` simulate it on ``spec``); on a small
    session of random commands, every candidate term and the simulated one: its fields, offsets of
    the documented shapes, finite, and none at theta = 0 (diagnosis nests every model in the one
    without it), back from its stored form, a regressor per pose, and for a recording artefact its
    onset, moved marker and correction sentence.
    """
    if isinstance(effect, ImuEffect):
        return check_imu_effect(effect, seed)
    assert isinstance(effect, Effect), f"{effect!r}: not a platkit.effects.Effect"
    name = effect.name
    assert isinstance(name, str) and name, f"{effect!r}: an effect needs a name"
    assert isinstance(effect.summary, str) and effect.summary, f"{name}: an effect needs a one-line summary"
    for flag in ("recording", "direction", "unsettled_holds"):
        assert isinstance(getattr(effect, flag), bool), f"{name}: {flag} must be True or False"
    assert not effect.unsettled_holds or effect.recording, \
        f"{name}: an unsettled_holds effect is an artefact of the recording (recording = True)"
    assert isinstance(effect.not_separable_advice, str), f"{name}: not_separable_advice must be a string"
    rng = np.random.default_rng(seed)
    poses, residuals = _effect_session(spec, rng)
    terms: list[tuple[ModelTerm, np.ndarray | None]] = [(t, None) for t in effect.candidates(spec, poses, residuals)]
    made = effect.simulation_term(spec, None, rng, poses)
    plan = PhysicsPlan(spec, np.asarray(poses.t, float), poses.controls, spec.neutral_u(), 1.0,
                       float(poses.t[-1]) + 2.0, list(poses.marker_names))
    physics = effect.physics(spec, None, rng, plan)
    for physical, simulated in ((False, made is not None), (True, physics is not None)):
        told = effect.size_help(physical)
        mode = "physics" if physical else "simulation_term"
        assert told is None or (isinstance(told, SizeHelp) and told.meaning and isinstance(told.unit, str)), \
            f"{name}: size_help({physical}) must be a SizeHelp with a meaning and a unit, or None"
        assert told is not None or not simulated, f"{name}: {mode} simulates the effect, but its size help is missing"
    if made is not None:
        term, theta = made
        assert np.all(np.isfinite(np.asarray(theta, float))), f"{name}: simulation_term's theta is not finite"
        terms.append((term, np.asarray(theta, float)))
    if physics is not None:
        assert isinstance(physics, EffectPhysics) and isinstance(physics.parameters(), dict), \
            f"{name}: physics must give an EffectPhysics whose parameters() is a mapping"
    for term, theta in terms:
        _check_term(effect, term, spec, poses, theta, rng)
    return {"effect": name, "stand": spec.name, "terms": len(terms), "recording": effect.recording,
            "simulated": made is not None, "physics": physics is not None}
