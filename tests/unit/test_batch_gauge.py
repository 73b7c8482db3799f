"""One parameterisation for every session of a fleet or a history (platkit.batch.gauge): a static
stand calibrated month after month, with its own noise, plan, motion-capture frame and markers
each month, gives no change and no parameter that moved, on every built-in stand; a knock of one
leg is flagged once, in its month, on its leg, at its size."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.batch.fleet import moved_parameters
from platkit.batch.gauge import common_parameterisation, reference_free
from platkit.batch.history import stand_history
from platkit.calibrate.estimate import calibrate
from platkit.calibrate.plan import default_marker_layout, identification_jacobian, reference_poses_for
from platkit.errors import BadInput
from platkit.plugins import get_platform
from platkit.simulate import perturb_parameters, simulate

MONTHS = 8
TABLE_KEYS = ("value", "std", "nominal", "unit", "status")


def table(cal) -> dict[str, dict]:
    """The parameter table of calibration.yaml (as platkit.batch.fleet.parameter_table reads it)."""
    return {n: {k: p[k] for k in TABLE_KEYS} for n, p in cal.to_dict()["parameters"].items()}


def along_the_gauge(spec, size: float, seed: int) -> np.ndarray:
    """A true td that differs from the drawing only along directions no pose can see: a random
    null vector of the identification Jacobian (stand, transform, markers) over the stand's
    reference poses, its stand part scaled to ``size`` typical corrections (mm, mrad) at most."""
    U, P = reference_poses_for(spec)
    ij = identification_jacobian(spec, U, default_marker_layout(spec, 5, np.random.default_rng(0)), P=P)
    scale = np.array([1e-3 if u in ("m", "rad", "1", "") else 1.0 for u in ij.units])
    J = ij.J.reshape(-1, len(ij.names)) * scale
    _, s, Vt = np.linalg.svd(J, full_matrices=False)
    null = Vt[np.sum(s > 1e-9 * s[0]):].T  # (n, k)
    d = null @ np.random.default_rng(seed).normal(size=null.shape[1])
    d_td = d[:ij.n_td] * scale[:ij.n_td]
    td = spec.nominal_td().copy()
    free = [i for i, p in enumerate(spec.parameters) if p.free]
    td[free] += size * d_td / np.max(np.abs(d[:ij.n_td]))
    return td


def months(truth_for_month, spec, free, n_poses=20, noise_mm=0.05, n_months=MONTHS):
    """Calibrations of ``n_months`` sessions, each with its own seed: noise, random plan, frame, markers."""
    out = []
    for m in range(n_months):
        sim = simulate(spec.with_td(truth_for_month(m)), seed=4100 + m, n_poses=n_poses, raw=False, perturbation=0.0,
                       plan="random", noise_mm=noise_mm, n_markers=4)
        out.append(calibrate(sim.poses, spec, free=free))
    return out


@pytest.mark.parametrize("stand", ["stewart", "psvr", "rotary"])
def test_a_static_stand_over_eight_months_gives_no_change_and_no_parameter_moving(stand):
    """A stand a few mm off its drawing (2 mm, 2 mrad per parameter), unchanged for eight months."""
    spec = get_platform(stand)
    param = common_parameterisation(spec)  # every group the stand frees by default
    truth = perturb_parameters(spec, np.random.default_rng(99))
    cals = months(lambda m: truth, spec, param.free)
    tables = [table(c) for c in cals]
    held = {n for n, s in zip(spec.parameter_names, cals[0].td_status) if s != "estimated"}
    assert held == set(param.gauge) and all(  # the batch's gauge, the same every month
        {n for n, s in zip(spec.parameter_names, c.td_status) if s != "estimated"} == held for c in cals)
    h = stand_history([f"month{m + 1}" for m in range(MONTHS)], tables, [None] * MONTHS)
    assert h["changes"] == []
    z = np.array([[np.nan if x is None else x for x in row] for row in h["z"]], float)[1:]
    tested = [j for j, n in enumerate(h["parameter_names"]) if n in param.free]
    assert len(tested) == len(param.free) and np.all(np.nanmedian(np.abs(z[:, tested]), axis=0) < 1.5)
    assert h["dispersion_k"] < 1.5  # the month-to-month scatter is what the stds say


def test_a_stand_as_drawn_up_to_a_symmetry_has_nothing_moved():
    """The fleet's 'moved': a stand that differs from its drawing only along a gauge (no pose can
    tell it from the drawing) has no parameter moved in any month, each median z within noise."""
    spec = get_platform("stewart")
    param = common_parameterisation(spec)
    truth = along_the_gauge(spec, 2.0, seed=7)
    assert np.max(np.abs(truth - spec.nominal_td())) > 1e-3  # a mm off the drawing, unseen
    tables = [table(c) for c in months(lambda m: truth, spec, param.free, n_months=4)]
    assert all(moved_parameters(t) == [] for t in tables)
    z = np.array([[(t[n]["value"] - t[n]["nominal"]) / t[n]["std"] for n in param.free] for t in tables])
    assert np.all(np.abs(np.median(z, axis=0)) < 2.0)


def test_the_per_session_gauge_is_what_made_a_static_stand_change():
    """The counter-case: the same stewart months calibrated each in the held set its own data
    choose (as a single calibration does) are in different gauges: between two months, parameters
    estimated in both differ by far more than their stds explain, on a stand that never changed."""
    spec = get_platform("stewart")
    truth = perturb_parameters(spec, np.random.default_rng(99))
    a, b = [table(c) for c in months(lambda m: truth, spec, None, n_months=2)]
    assert {n for n in a if a[n]["status"] != "estimated"} != {n for n in b if b[n]["status"] != "estimated"}
    both = [n for n in a if a[n]["status"] == b[n]["status"] == "estimated"]
    z = [abs(a[n]["value"] - b[n]["value"]) / np.hypot(a[n]["std"], b[n]["std"]) for n in both]
    assert max(z) > 6


def test_a_knock_of_one_leg_is_flagged_once_in_its_month_on_its_leg_at_its_size():
    spec = get_platform("stewart")
    legs = [p.name for p in spec.parameters if p.group == "leg_offsets"]
    param = common_parameterisation(spec, ["leg_offsets"])
    assert param.free == legs and not param.gauge
    drawing_error = spec.nominal_td() + np.array([{legs[1]: 8e-4, legs[3]: -6e-4}.get(n, 0.0)
                                                  for n in spec.parameter_names])
    knock = np.array([5e-4 if n == legs[2] else 0.0 for n in spec.parameter_names])
    cals = months(lambda m: drawing_error + (knock if m >= 4 else 0.0), spec, param.free, n_poses=24)
    h = stand_history([f"month{m + 1}" for m in range(MONTHS)], [table(c) for c in cals], [None] * MONTHS)
    assert [(f["parameter"], f["session"]) for f in h["changes"]] == [(legs[2], "month5")]
    assert h["changes"][0]["change"] == pytest.approx(0.5, abs=0.1)  # mm


def test_reference_calibration_decides_the_free_parameters(tmp_path):
    spec = get_platform("rotary")
    sim = simulate(spec, seed=3, n_poses=20, raw=False, plan="random", noise_mm=0.05, n_markers=4)
    cal = calibrate(sim.poses, spec, free=["scale", "origin"])
    from platkit.io.calibration import write_calibration_yaml

    path = write_calibration_yaml(cal, tmp_path)
    free = reference_free(path, spec)
    assert free == [n for n, s in zip(spec.parameter_names, cal.td_status) if s == "estimated"]
    param = common_parameterisation(spec, free, "reference")
    assert param.free == free and not param.gauge  # the reference's estimates hold no gauge
    with pytest.raises(BadInput, match="psvr"):
        reference_free(path, get_platform("psvr"))
    (tmp_path / "bad.yaml").write_text("parameters: 3\n")
    with pytest.raises(BadInput, match="bad.yaml: no 'parameters' mapping"):
        reference_free(tmp_path / "bad.yaml", spec)
