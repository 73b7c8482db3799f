"""Sessions made by platkit.simulate (raw marker streams settled by platkit.settle): the
example sessions shipped with platkit, and fresh ones. Calibration predicts the markers of the
true stand to well under the marker noise."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from platkit.calibrate.estimate import calibrate, predict_markers
from platkit.geometry import matrix_from_quat
from platkit.io.session import example_session, load_session
from platkit.kinematics import PlatformModel
from platkit.settle import load_poses


@pytest.mark.parametrize("stand", ["stewart", "psvr", "rotary"])
def test_example_session_predicts_the_true_markers(stand):
    folder = example_session(stand)
    session = load_session(folder)
    poses = load_poses(folder, spec=session.spec)
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    spec = session.spec
    td = np.array([truth["parameters"][n]["value"] for n in spec.parameter_names])
    T = np.array(truth["mocap_from_base"], float)
    body = np.array([truth["markers"][m] for m in poses.marker_names], float)
    fb = PlatformModel(spec).forward_batch(poses.controls, td, strict=False)
    true_markers = (fb.X[:, None] + np.einsum("nab,mb->nma", matrix_from_quat(fb.q), body)) @ T[:3, :3].T + T[:3, 3]
    cal = calibrate(poses, spec)
    pred, _, _, ok = predict_markers(cal, poses.controls)
    err = float(np.sqrt(np.mean(np.sum((pred[ok] - true_markers[ok]) ** 2, axis=2))))
    noise = truth["marker_noise_m"]
    assert ok.all() and cal.converged
    assert cal.rms_after < cal.rms_before
    # the settled markers average many samples; the model error must sit well below one sample's noise
    assert err < 0.5 * noise, f"{stand}: prediction error {err * 1e3:.4f} mm against the truth (noise {noise * 1e3} mm)"


@pytest.mark.parametrize("stand", ["urdf", "stewart"])
def test_simulated_session_with_the_simulator(stand):
    from platkit.plugins import get_platform
    from platkit.simulate import simulate

    spec = get_platform(stand)
    sim = simulate(spec, seed=7, n_poses=60, plan="random", noise_mm=0.2)
    poses, truth = sim.poses, sim.truth
    cal = calibrate(poses, spec)
    fb = PlatformModel(spec).forward_batch(poses.controls, truth.td, strict=False)
    T = truth.mocap_from_base
    true_markers = (fb.X[:, None] + np.einsum("nab,mb->nma", matrix_from_quat(fb.q), truth.markers)) @ T[:3, :3].T \
        + T[:3, 3]
    pred, _, _, ok = predict_markers(cal, poses.controls)
    err = float(np.sqrt(np.mean(np.sum((pred[ok] - true_markers[ok]) ** 2, axis=2))))
    assert ok.all() and err < 0.5 * truth.noise_m, f"{stand}: {err * 1e3:.4f} mm"
