"""What an estimator leaves beside its result (Calibration.fit, a FitRecord) and the options the
calibration's stages take (CalibrationOptions)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_estimate import Truth

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.report import write_outputs
from platkit.calibrate.solve import blas_threads
from platkit.calibrate.stages import CalibrationOptions, fit_calibration
from platkit.io.calibration import FitRecord, read_calibration
from platkit.plugins import get_platform


@pytest.fixture(scope="module")
def fitted():
    spec = get_platform("stewart")
    poses = Truth(spec, seed=5).poses(30, 1e-4)
    return spec, poses, calibrate(poses, spec, free=["platform_joints"])


def test_the_fit_record_holds_the_estimate_it_came_from(fitted):
    spec, poses, cal = fitted
    fit = cal.fit
    assert isinstance(fit, FitRecord)
    problem = fit.problem
    n_active = int(fit.active.sum())
    assert fit.z.shape == fit.active.shape == (problem.n_z,) and fit.cov.shape == (n_active, n_active)
    np.testing.assert_array_equal(fit.z[problem.i_td], cal.td)  # the unknowns at the estimate
    np.testing.assert_array_equal(fit.z[problem.i_m].reshape(-1, 3), cal.marker_positions)
    assert fit.residuals_after.shape == fit.residuals_before.shape == (poses.n_poses, poses.n_markers, 3)
    assert fit.weights.shape == (poses.n_poses, poses.n_markers)
    np.testing.assert_array_equal(fit.controls, poses.controls)
    # the standard deviations are the covariance's diagonal (td entries estimated, the gauge aside)
    std = np.sqrt(np.diag(fit.cov))[np.cumsum(fit.active)[problem.i_td][fit.active[problem.i_td]] - 1]
    np.testing.assert_allclose(cal.td_std[fit.active[problem.i_td]], std, rtol=1e-12)
    assert [n for n, st in zip(spec.parameter_names, cal.td_status) if st == "estimated"] == \
        [problem.names[i] for i in np.nonzero(fit.active[problem.i_td])[0]]
    with pytest.raises(dataclasses.FrozenInstanceError):
        fit.z = None


def test_a_calibration_read_back_has_no_fit_and_its_file_keeps_the_warnings(fitted, tmp_path):
    _, poses, cal = fitted
    cal = dataclasses.replace(cal, warnings=["check the markers"])
    write_outputs(cal, tmp_path / "out", poses, with_html=False)
    back = read_calibration(tmp_path / "out" / "calibration.yaml")
    assert back.fit is None and back.paper == {}
    assert back.to_dict()["parameters"] == cal.to_dict()["parameters"]
    assert "check the markers" in (tmp_path / "out" / "calibration.yaml").read_text()


def test_the_options_are_calibrate_s_keywords(fitted):
    spec, poses, cal = fitted
    with blas_threads(1):
        again = fit_calibration(poses, spec, (), CalibrationOptions(free=["platform_joints"]))
    np.testing.assert_array_equal(again.td, cal.td)
    np.testing.assert_array_equal(again.td_std, cal.td_std)
    assert again.identifiability == cal.identifiability and again.warnings == []
    with pytest.raises(TypeError):
        CalibrationOptions(["platform_joints"])  # keywords only
