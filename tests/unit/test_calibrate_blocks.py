"""The calibration solved block by block (CalibrationProblem.row_block): the blocks' rows are the
whole evaluation's, the normal equations and R factor summed over them are the whole Jacobian's
to rounding, a motion calibration gives the same fit as with the whole Jacobian, and its memory
stays near the stream's array (no array of every pose's Jacobian comes back). Sessions of the
physical simulator, fixed seeds."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import platkit.calibrate.motion as motion
from platkit.calibrate.estimate import predict_markers
from platkit.calibrate.solve import _normal_equations, _normal_equations_blocked, weighted_factor
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session


def _session(tmp_path, seed: int, duration_s: float, rate_hz: float):
    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=seed, motion="multisine", duration_s=duration_s, mocap_rate_hz=rate_hz)
    write_physical_session(sim, tmp_path / f"s{seed}")
    return sim, load_session(tmp_path / f"s{seed}")


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    sim, session = _session(tmp_path_factory.mktemp("blocks"), 4201, 24.0, 50.0)
    cal, poses = motion.calibrate_motion(session, session.spec)
    return sim, session, cal, poses


def test_blocks_are_the_whole_evaluation(fitted):
    """Each block's residuals and Jacobian (with the response term's columns) are the whole
    evaluation's rows; H, g and R over the blocks are the whole Jacobian's to rounding."""
    _, _, cal, _ = fitted
    problem, z, active = cal.fit.problem, cal.fit.z, cal.fit.active
    assert problem.row_block == motion.ROW_BLOCK and problem.terms
    whole = problem.evaluate(z, with_jac=True)
    assert whole.J is not None
    n = 0
    for rows, part in problem.evaluate_blocks(z, 50):
        assert np.allclose(part.r, whole.r[rows], rtol=0, atol=1e-15, equal_nan=True)
        assert np.allclose(part.J, whole.J[rows], rtol=1e-12, atol=1e-15)
        n += rows.stop - rows.start
    assert n == problem.N
    w = cal.fit.weights
    rw, H, g = _normal_equations(whole, w, active)
    rw_b, H_b, g_b = _normal_equations_blocked(problem, z, problem.evaluate(z, with_jac=False), w, active)
    assert np.array_equal(rw, rw_b)
    scale = np.sqrt(np.diag(H))
    assert np.allclose(H_b / np.outer(scale, scale), H / np.outer(scale, scale), rtol=0, atol=1e-10)
    # g vanishes at the fit: compared with its terms' size, |column| |residuals|
    assert np.allclose(g_b, g, rtol=0, atol=1e-10 * scale * np.linalg.norm(rw))
    R = weighted_factor(problem, z, whole, w, active)
    assert np.allclose(R.T @ R / np.outer(scale, scale), H / np.outer(scale, scale), rtol=0, atol=1e-10)


def test_motion_fit_by_blocks_is_the_whole_fit(fitted, monkeypatch):
    """The same session calibrated with the whole Jacobian (row_block None): the same residual RMS
    and the same predictions of the settled poses to rounding."""
    sim, session, cal, _ = fitted
    monkeypatch.setattr(motion, "ROW_BLOCK", None)
    whole, _ = motion.calibrate_motion(session, session.spec)
    assert whole.fit.problem.row_block is None
    assert abs(whole.rms_after - cal.rms_after) <= 1e-9 * cal.rms_after
    pred, _, _, _ = predict_markers(cal, sim.commands)
    pred_whole, _, _, _ = predict_markers(whole, sim.commands)
    assert np.nanmax(np.abs(pred - pred_whole)) < 1e-9  # m
    for name in ("shift_s",):
        assert abs(cal.motion["response"][name]["value"] - whole.motion["response"][name]["value"]) < 1e-9


#: a fit's peak traced memory (numpy's arrays included) in units of its stream's marker array: two
#: minutes at 120 Hz measured 8.3 by blocks, 73 with the Jacobian of every pose at once (its copies
#: from the observation function, the assembly and the weighting: 17 MB each) (2026-11-27)
PEAK_PER_STREAM = 16.0


def test_memory_of_a_long_stream_stays_near_its_array(tmp_path):
    """Two minutes of 120 Hz motion capture, 5 markers: the fit's peak traced memory is under
    PEAK_PER_STREAM times the stream's marker array."""
    _, session = _session(tmp_path, 4202, 120.0, 120.0)
    stream = session.markers.nbytes
    tracemalloc.start()
    try:
        motion.calibrate_motion(session, session.spec)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < PEAK_PER_STREAM * stream, f"peak {peak / 1e6:.1f} MB, stream {stream / 1e6:.2f} MB"
