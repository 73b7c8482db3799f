"""Calibration from motion leaves out the first command's transient (platkit.calibrate.
motion_transient): the stand's state before the first command is not logged, so the samples its
free response still moves must not drive the fit. A small Stewart stream of the physical
simulator (fixed seed) whose logged first command lies 80 mm of leg from where the stand rests
(the stand's motion after the first command is the model's plus the free response from that
offset, as for a stand resting away from the first command)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from stream_split import written_stream

from platkit.calibrate.estimate import predict_markers
from platkit.calibrate.motion import calibrate_motion, motion_stream
from platkit.calibrate.motion_start import response_start
from platkit.calibrate.motion_transient import GROSS, noise_3d, settle_time_s, start_transient
from platkit.calibrate.response import ResponseModel
from platkit.calibrate.stream import stream_windows

OFFSET_M = 0.08


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    sim, session = written_stream(tmp_path_factory.mktemp("transient") / "session", seed=4101, duration_s=12.0)
    U = session.commands.copy()
    U[0] += OFFSET_M  # the first command logged away from where the stand rests
    return sim, session, dataclasses.replace(session, commands=U)


def test_a_stream_that_starts_on_its_first_command_leaves_nothing_out(streamed):
    _, session, _ = streamed
    rmodel = ResponseModel("first_order", "step", session.spec.n_u)
    win = stream_windows(session)
    theta, start, geom = response_start(session, session.spec, rmodel, win)
    said = start_transient(session, session.spec, rmodel, theta, geom, win.first, start)
    assert said["n_samples"] == 0 and said["until_s"] is None and "said" not in said


def test_the_first_commands_transient_is_left_out_counted_and_said(streamed):
    sim, _, far = streamed
    cal, _ = calibrate_motion(far, far.spec, kind="second_order")
    samples = cal.motion["samples"]
    transient = samples["start_transient"]
    n = samples["n_in_start_transient"]
    assert n == transient["n_samples"] > 0
    # the samples it spans: from the second command until the free response has decayed
    assert transient["from_s"] < transient["gross_until_s"] < transient["until_s"]
    assert n == int(np.sum((far.marker_t >= far.command_t[1]) & (far.marker_t < transient["until_s"])))
    # the tail: until the gross bound has decayed, at the slowest response, to a tenth of the
    # markers' own 3-D noise (not to the noise: the transient left would be as large as the noise)
    assert 0 < transient["noise_3d_m"] < GROSS * transient["residual_scale_m"]
    decay = np.log(GROSS * transient["residual_scale_m"] / (0.1 * transient["noise_3d_m"]))
    assert transient["tail_s"] == pytest.approx(transient["settle_tau_s"] * decay, rel=1e-9)
    # every sample counted once: used, in the transient, before the second command, unseen or short
    assert (samples["n_used"] + n + samples["n_before_second_command"] + samples["n_unseen"]
            + samples["n_in_short_windows"]) == samples["n_stream"]
    assert any(f"({n} samples) left out" in w and "first command's transient" in w for w in cal.warnings)
    # the response and the stand recovered (the transient in the fit walks every time constant
    # 40-70 % up, the clock shift 30 ms off and the stand to 0.3 mm)
    r = cal.motion["response"]
    taus = np.array([r["actuators"][c]["tau_s"]["value"] for c in far.spec.control_names])
    assert np.all(np.abs(taus / sim.response.tau_s - 1) < 0.1)
    assert abs(r["shift_s"]["value"] - sim.nuisances.time_shift_s) < 3e-3
    assert samples["n_fitted_rejected_as_outliers"] < 20
    pred, _, _, _ = predict_markers(cal, sim.commands)
    assert np.sqrt(np.nanmean(np.sum((pred - sim.settled_markers) ** 2, axis=2))) < 0.08e-3
    # a diagnosis reads the same stream without it (the rule at the calibration), and says so
    poses, term = motion_stream(far, cal)
    assert term.start_transient["n_samples"] > 0
    assert poses.t.min() >= term.start_transient["until_s"] - 1e-9


def test_the_transients_decay_bound_and_the_markers_noise():
    """The slowest free response among the actuators moved (a first order's tau; a second
    order's tau max(2 zeta, 1 / zeta)), and the markers' 3-D noise from pairs on one link alone."""
    first = ResponseModel("first_order", "step", 3)
    assert settle_time_s(first, [0.0, 0.05, 0.2, 0.1], np.array([True, False, True])) == pytest.approx(0.1)
    second = ResponseModel("second_order", "step", 2)  # theta: shift, tau (2), damping (2)
    assert settle_time_s(second, [0.0, 0.05, 0.04, 2.0, 1.0], np.array([True, True])) == pytest.approx(0.2)
    assert settle_time_s(second, [0.0, 0.05, 0.04, 0.25, 1.0], np.array([True, True])) == pytest.approx(0.2)
    rng = np.random.default_rng(0)
    K, sigma = 4000, 2e-4
    # two links, two markers each; the links move apart (pairs across links are not rigid)
    base = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.0, 0, 0], [0.0, 0.1, 0]])
    move = np.zeros((K, 4, 3))
    move[:, 2:] = rng.uniform(-0.3, 0.3, (K, 1, 3))
    Y = base + move + rng.normal(0, sigma, (K, 4, 3))
    assert noise_3d(Y, np.array([0, 0, 1, 1])) == pytest.approx(np.sqrt(3) * sigma, rel=0.1)
    assert np.isnan(noise_3d(Y[:, [0, 2]], np.array([0, 1])))  # no link carries two markers

