"""Calibration from motion leaves out the samples past the end of a command log cut in motion
(platkit.calibrate.stream.past_log_end): there the stand follows commands the log does not have,
which the response would read as the last command held. A small Stewart stream of the physical
simulator (fixed seed), its command log cut CUT_S before its end (a log that stops while the
stand moves, the markers recorded on to the stand's rest on the simulator's last command); the
same stream whole, whose log slows to that last command, which the stand then holds (at rest),
keeps every sample."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from stream_split import written_stream

from platkit.calibrate.estimate import predict_markers
from platkit.calibrate.motion import calibrate_motion, motion_stream
from platkit.calibrate.stream import log_end, past_log_end, stream_windows

CUT_S = 2.0


@pytest.fixture(scope="module")
def streams(tmp_path_factory):
    sim, whole = written_stream(tmp_path_factory.mktemp("log_cut") / "session", seed=4101, duration_s=12.0)
    keep = whole.command_t < whole.command_t[-1] - CUT_S
    cut = dataclasses.replace(whole, command_t=whole.command_t[keep], commands=whole.commands[keep])
    return sim, whole, cut


def seen(session) -> np.ndarray:
    return np.isfinite(session.markers).all(axis=2).any(axis=1)


def test_a_log_cut_in_motion_ends_there_and_a_log_at_rest_does_not(streams):
    _, whole, cut = streams
    # the simulator's log slows to its last command (each actuator's last step still over a tenth
    # of its median step), which the stand then holds: the markers, still after it, say so
    assert log_end(whole.command_t, whole.commands) is not None
    assert past_log_end(whole, "step", [0.05], 0.5) is None
    end = log_end(cut.command_t, cut.commands)
    assert end == pytest.approx(cut.command_t[-1] + np.median(np.diff(cut.command_t)))
    assert past_log_end(cut, "step", [0.05], 0.5) == pytest.approx(end + 0.05)
    assert past_log_end(cut, "profile", [0.05], 0.5) is None  # a profile's last command is a hold's target
    # the windows stop there, the samples after counted
    win = stream_windows(cut, end_t=end)
    past = seen(cut) & (cut.marker_t > end)
    assert win.n_past_log == int(past.sum()) > 0 and win.end == len(cut.marker_t) - len(past.nonzero()[0])
    assert win.sample_t[-1] <= end and win.t.max() <= end


def test_the_samples_past_a_log_cut_in_motion_are_left_out_counted_and_said(streams):
    sim, _, cut = streams
    cal, poses = calibrate_motion(cut, cut.spec, kind="second_order")
    samples = cal.motion["samples"]
    end_t = samples["log_end_s"]
    # the log's end read through the response's lag at its start: about the clock shift (14 ms short)
    lag = end_t - log_end(cut.command_t, cut.commands)
    assert lag == pytest.approx(sim.nuisances.time_shift_s, abs=0.03)
    n = samples["n_past_the_log"]
    assert n == int(np.sum(seen(cut) & (cut.marker_t > end_t))) > 0.8 * CUT_S * 50
    # not fitted: no pose after it; every sample counted once
    assert poses.t.max() <= end_t
    assert (samples["n_used"] + n + samples["n_before_second_command"] + samples["n_in_start_transient"]
            + samples["n_unseen"] + samples["n_in_short_windows"]) == samples["n_stream"]
    assert any(f"{n} samples after" in w and "commands.csv: the command log ends in motion" in w
               for w in cal.warnings)
    # the stand recovered as from a log that covers the stream (0.04 mm from the whole stream; with
    # the samples past the log fitted, read as the last command held, the markers are off by
    # centimetres and the fit is refused: MotionUnexplained)
    assert samples["n_fitted_rejected_as_outliers"] < 20
    pred, _, _, _ = predict_markers(cal, sim.commands)
    assert np.sqrt(np.nanmean(np.sum((pred - sim.settled_markers) ** 2, axis=2))) < 0.08e-3
    # a diagnosis reads the same stream without them (the rule at the calibration's response)
    stream, term = motion_stream(cut, cal)
    assert term.past_the_log["n_samples"] > 0.8 * CUT_S * 50
    assert stream.t.max() <= term.past_the_log["log_end_s"]
