"""A stream's windowed poses (nodes about a third of a second apart) share the motion capture's
coloured noise (a part correlated over tenths of a second, which a window's fit does not average
away): the location tests in time and over near commands read it as structure. Where the geometric
model predicts held-out poses within ``lack_of_fit_factor`` times the noise floor, that structure is
not reported as ``unexplained`` (platkit.diagnose.search.structure_left, lack_of_fit), as beside a
modelled effect; settled poses keep the tests' verdict."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from platkit.diagnose.search import diagnose
from platkit.plugins import get_platform
from platkit.simulate import simulate
from platkit_effects import Backlash

SAMPLES = 30  # what a node is worth
SIGMA = 2e-4  # m, one sample's white noise per coordinate


def _windowed(coloured_m: float, correlation_nodes: float, windowed: bool = True, seed: int = 7):
    """Noise-free settled poses of a psvr stand in command order, given the noise of windowed poses:
    white noise of SIGMA over SAMPLES samples, plus first-order noise of ``coloured_m`` per
    coordinate correlated over ``correlation_nodes`` poses; the nodes marked where ``windowed``."""
    spec = get_platform("psvr")
    poses = simulate(spec, seed=seed, n_poses=300, plan="random", raw=False, noise_mm=0.0).poses
    rng = np.random.default_rng(seed)
    shape = poses.markers.shape
    a = np.exp(-1.0 / correlation_nodes)
    coloured = lfilter([np.sqrt(1 - a * a)], [1.0, -a], rng.normal(size=shape), axis=0) * coloured_m
    poses.markers = poses.markers + rng.normal(size=shape) * SIGMA / np.sqrt(SAMPLES) + coloured
    poses.n_samples = np.full(shape[:2], float(SAMPLES))
    poses.settling = {"point_sigma_m": {m: SIGMA for m in poses.marker_names}}
    if windowed:
        poses.extras = {**poses.extras, "node": np.arange(poses.n_poses), "elapsed": np.arange(poses.n_poses) / 3.0}
    return spec, poses


@pytest.mark.parametrize("share, correlation_nodes", [(1.0, 1.0), (1.5, 2.0)])
def test_coloured_noise_at_windowed_poses_is_not_unexplained(share, correlation_nodes):
    """Before: ``unexplained`` from residuals alike at poses next in time (lack_of_fit's neighbour
    tests, at 1.4 times the floor), and from autocorrelation in time (Ljung-Box, located, at 1.8
    times); the same poses taken as settled keep it."""
    spec, poses = _windowed(share * SIGMA / np.sqrt(SAMPLES), correlation_nodes)
    d = diagnose(spec, poses, library={"backlash": Backlash()})
    assert [f.effect for f in d.findings] == [], [(f.effect, f.where, f.evidence) for f in d.findings]
    assert d.heldout_geometric <= 2.0 * d.noise_floor  # within the factor: the tests alone are not evidence
    spec, settled = _windowed(share * SIGMA / np.sqrt(SAMPLES), correlation_nodes, windowed=False)
    assert [f.effect for f in diagnose(spec, settled, library={"backlash": Backlash()}).findings] == ["unexplained"]
