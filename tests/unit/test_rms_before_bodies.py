"""rms_before and rms_after run over the same observations (those the final fit keeps): on a
session of one rigid body, whose declared noise is far below the nominal stand's error, the
registration's own robust loss rejects most of the body's origins, and an RMS over what it kept
would read a fraction of the nominal error and call a good fit worse than its start."""
from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest
import yaml
from bodies_alone import strip_markers

from platkit.calibrate.estimate import calibrate
from platkit.cli import main
from platkit.commands.calibrate import load_for_calibration


@pytest.fixture(scope="module")
def body_session(tmp_path_factory):
    root = tmp_path_factory.mktemp("rms_before")
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        assert main(["simulate", "--platform", "stewart", "--out", str(root / "s"), "--seed", "202", "--poses", "40",
                     "--plan", "random", "--rigid-bodies", "1", "--effect", "backlash:1.0"]) == 0
    return strip_markers(root / "s", root / "b")


def test_rms_before_runs_over_the_observations_the_fit_kept(body_session):
    with contextlib.redirect_stderr(io.StringIO()):
        poses, spec, opts = load_for_calibration(str(body_session), None, None, quiet=True)
        cal = calibrate(poses, spec, free=["base_joints", "platform_joints", "leg_offsets"], platform_options=opts)
    fit = cal.fit
    assert poses.n_markers == 0 and poses.n_bodies == 1
    # the registration's own loss kept few of the origins: the case this rule is for
    assert (fit.weights_before[:, 0] > 0).sum() < 0.5 * poses.n_poses
    kept = (fit.weights > 0) & np.isfinite(fit.residuals_before).all(axis=2)
    d2 = np.sum(np.nan_to_num(fit.residuals_before) ** 2, axis=2)
    assert cal.rms_before == pytest.approx(np.sqrt(np.mean(d2[kept])), rel=1e-12)
    assert cal.rms_before > 2 * cal.rms_after


def test_calibrate_of_one_body_is_not_called_worse_than_its_start(body_session, tmp_path):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main(["calibrate", str(body_session), "--out", str(tmp_path / "cal"), "--no-report"])
    assert rc == 0, err.getvalue()[-400:]
    rep = yaml.safe_load((tmp_path / "cal" / "report.json").read_text())
    assert rep["rms_before"] > 2 * rep["rms_after"]
