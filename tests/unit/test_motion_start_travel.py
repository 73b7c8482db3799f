"""The actuators' travel that starts the response of calibration from motion
(platkit.calibrate.motion_start) on a stand of fewer than six degrees of freedom.

The stand: rotary (two revolute joints, no closed-form inverse). The pose of noisy markers (by
Kabsch) is never exactly on its two-dimensional reach, so its inverse kinematics refused every
sample: the travel was all NaN and the start kept the starting response (no shift, 50 ms, a
stroke in 4 s) without a word. Rotary 2722060 (settling_lag, calibrated from motion) then started
its fit 28-95 mm off, and whether the fit's own registration found the frame was chance."""
from __future__ import annotations

import warnings

import numpy as np
import yaml

from platkit.calibrate.motion_start import actuator_travel, marker_points, response_start, starting_theta
from platkit.calibrate.response import ResponseModel
from platkit.calibrate.stream import stream_windows
from platkit.io.session import load_session
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session


def test_a_two_joint_stand_has_travel_from_noisy_markers():
    """Markers 0.05 mm noisy on the rotary stand: the travel is each sample's controls to within
    0.05 degrees (the controls whose markers come nearest), not NaN (before: every sample)."""
    spec = get_platform("rotary")
    model = PlatformModel(spec)
    rng = np.random.default_rng(3)
    U = rng.uniform(-60.0, 60.0, size=(40, 2))
    mk = rng.uniform(-0.15, 0.15, size=(5, 3))
    td = spec.nominal_td()
    A = np.eye(3)
    b = np.array([0.1, -0.2, 0.05])
    Y = marker_points(spec, model, td, mk, None, U) + b + rng.normal(scale=5e-5, size=(40, 5, 3))
    Y[0, :3] = np.nan  # two markers seen: left out
    travel = actuator_travel(spec, model, td, A, b, mk, Y, U + rng.normal(scale=2.0, size=U.shape))
    assert np.isnan(travel[0]).all()
    assert np.isfinite(travel[1:]).all()
    assert np.abs(travel[1:] - U[1:]).max() < 0.05


def test_the_start_fits_the_response_of_a_two_joint_stand(tmp_path):
    """A rotary session of 20 random holds (seed 1): the start's response is fitted (before: the
    starting response itself, rates 0.98 and 1.21 of the drawn, no shift): rates within 2 % of the
    drawn, the shift within 50 ms of the markers' clock offset."""
    spec = get_platform("rotary")
    sim = simulate_physics(spec, seed=1, n_poses=20, plan="random")
    folder = tmp_path / "session"
    write_physical_session(sim, folder)
    session = load_session(folder, quiet=True)
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    rmodel = ResponseModel("first_order", "profile", spec.n_u)
    theta, _, _ = response_start(session, spec, rmodel, stream_windows(session))
    assert not np.array_equal(theta, starting_theta(rmodel, spec))
    rates = theta[[rmodel.index("rate", j) for j in range(spec.n_u)]]
    drawn = np.array([truth["nuisances"]["actuators"][c]["rate_per_s"] for c in spec.control_names])
    assert np.all(np.abs(rates / drawn - 1) < 0.02)
    assert abs(theta[0] - truth["nuisances"]["markers_time_minus_exposure_time_s"]) < 0.05


def test_a_start_whose_travel_reaches_too_few_samples_is_registered_again(tmp_path, monkeypatch):
    """The registration on the slowest quarter can turn a two-joint stand's frame (rotary
    3510060: 133 degrees off, no sample's travel reached, the start the starting response); the
    start is then taken with the registration on the slowest eighth, half and every window in
    turn, the first whose travel reaches half its samples kept (there: the eighth, 0.2 degrees).
    Here the rounds are replaced by a record of the rows each is given and a reach per share."""
    import platkit.calibrate.motion_start as ms

    spec = get_platform("rotary")
    sim = simulate_physics(spec, seed=1, n_poses=20, plan="random")
    write_physical_session(sim, tmp_path / "session")
    session = load_session(tmp_path / "session", quiet=True)
    win = stream_windows(session)
    shares = {int(ms.slowest_rows(win, s).sum()): s for s in (ms.STILL_SHARE,) + ms.OTHER_SHARES}
    assert len(shares) == 4  # four different sets of rows
    rmodel = ResponseModel("first_order", "profile", spec.n_u)

    def run(reach):
        calls = []

        def rounds(session, spec, rmodel, win, still, *args):
            share = shares[int(still.sum())]
            calls.append(share)
            return share, None, None, reach[share]

        monkeypatch.setattr(ms, "_start_on", rounds)
        return ms.response_start(session, spec, rmodel, win)[0], calls

    assert run({0.25: 0.9, 0.125: 1.0, 0.5: 1.0, 1.0: 1.0}) == (0.25, [0.25])
    assert run({0.25: 0.0, 0.125: 0.3, 0.5: 0.6, 1.0: 1.0}) == (0.5, [0.25, 0.125, 0.5])
    assert run({0.25: 0.1, 0.125: 0.0, 0.5: 0.3, 1.0: 0.2}) == (0.5, [0.25, 0.125, 0.5, 1.0])


def test_a_start_that_reaches_too_few_samples_at_every_registration_says_so(tmp_path, monkeypatch):
    """Where no registration's travel reaches half its samples, the start is kept (the one that
    reached most) and a warning says on how many it read the travel; a start that reaches half
    says nothing."""
    import platkit.calibrate.motion_start as ms

    spec = get_platform("rotary")
    sim = simulate_physics(spec, seed=1, n_poses=20, plan="random")
    write_physical_session(sim, tmp_path / "session")
    session = load_session(tmp_path / "session", quiet=True)
    win = stream_windows(session)
    rmodel = ResponseModel("first_order", "profile", spec.n_u)
    for reach, said in ((0.0, "the starting response"), (0.3, "30% of its"), (0.9, None)):
        monkeypatch.setattr(ms, "_start_on", lambda *args, r=reach: ("theta", None, None, r))
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            ms.response_start(session, spec, rmodel, win)
        texts = [str(w.message) for w in got if "response's start" in str(w.message)]
        if said is None:
            assert texts == []
        else:
            assert len(texts) == 1 and said in texts[0] and "4 registrations tried" in texts[0]


def test_a_sample_whose_step_fails_the_kinematics_keeps_its_place(monkeypatch):
    """Where a control's finite-difference step takes a sample out of the kinematics (NaN markers),
    that sample's Gauss-Newton step moves nothing and the sample ends NaN or where it stood, and
    the other samples' travel is found: before, the NaN column made the solve NaN, the next
    evaluation raised BadInput ("control A is not a finite number") and calibration from motion
    stopped (psvr 5470190)."""
    import platkit.calibrate.motion_start as ms

    spec = get_platform("rotary")
    model = PlatformModel(spec)
    rng = np.random.default_rng(5)
    U = rng.uniform(-40.0, 40.0, size=(20, 2))
    U[7, 0] = 59.0  # the sample whose first control's step fails
    mk = rng.uniform(-0.15, 0.15, size=(5, 3))
    td = spec.nominal_td()
    b = np.zeros(3)
    Y = marker_points(spec, model, td, mk, None, U) + rng.normal(scale=5e-5, size=(20, 5, 3))
    guess = U.copy()
    edge = U[7, 0] + 0.5 * ms.TRAVEL_STEP
    real = ms.marker_points

    def failing(spec_, model_, td_, mk_, links_, U_, guess=None):
        pts = real(spec_, model_, td_, mk_, links_, U_, guess)
        pts[np.asarray(U_)[:, 0] > edge] = np.nan
        return pts

    monkeypatch.setattr(ms, "marker_points", failing)
    travel = actuator_travel(spec, model, td, np.eye(3), b, mk, Y, guess)
    others = np.delete(np.arange(20), 7)
    assert np.isfinite(travel[others]).all()
    assert np.abs(travel[others] - U[others]).max() < 0.05
