"""The prior on the tree's mass moments estimated with the compliances (no inertias):
plugins/platkit_effects/tree_joints.py, its rows in the estimator (ModelTerm.prior)."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.problem import CalibrationProblem
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit_effects import Compliance
from platkit_effects.tree_compliance import tree_stand
from platkit_effects.tree_joints import DETERMINED, JointsComplianceTerm, joints_compliance_term, tree_mass_basis
from tests.unit.test_tree_loads import _tree

LINKS = {"L": "l_lo", "R": "r_lo"}
NOISE_M = 1e-4


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """A two-armed tree without inertias, 40 poses whose markers are its every-joint term with all
    10 identifiable mass-moment combinations at known values (one of them 0.5 prior standard
    deviations, the others at the prior), plus mocap noise of NOISE_M per coordinate."""
    spec = get_platform("urdf", _tree(tmp_path_factory.mktemp("bare"), masses=False), moving_link=LINKS)
    n = 40
    C = np.random.default_rng(3).uniform(-1.0, 1.0, (n, 5)) * [1.0, 1.2, 1.2, 0.2, 1.2]
    empty = PoseSet(spec.name, C, np.zeros((n, 2, 3)), ["L", "R"], length_unit="m", moving_link=LINKS)
    group = next(t for t in Compliance().candidates(spec, empty) if isinstance(t, JointsComplianceTerm))
    J = len(group.indices)
    c = np.array([-2e-3, -4e-3, 1e-3])
    stand = tree_stand(spec)
    B, rank = tree_mass_basis(stand, C, group.joints, c * stand.scale[group.indices], 16)
    K = B.shape[1]
    truth = np.zeros(K)
    truth[2] = 0.5
    term = joints_compliance_term("compliance", spec, group.indices, masses=B, identifiable=rank)
    problem = CalibrationProblem(spec, empty, [term])
    z = np.zeros(problem.n_z)
    z[problem.i_td] = spec.nominal_td()
    z[problem.i_m] = [0.05, 0.01, -0.02, 0.02, 0.03, 0.04]
    z[problem.i_theta] = np.concatenate([c, truth])
    markers = problem.evaluate(z, with_jac=False).r  # the model's markers (observed at zero)
    markers = markers + np.random.default_rng(7).normal(0.0, NOISE_M, markers.shape)
    poses = PoseSet(spec.name, C, markers, ["L", "R"], length_unit="m", moving_link=LINKS)

    def fit(noise_m: float):
        t = joints_compliance_term("compliance", spec, group.indices, masses=B, identifiable=rank,
                                   noise_m=noise_m)
        t.initial = np.concatenate([c, np.zeros(K)])
        cal = calibrate(poses, spec, terms=[t], free=[])
        return t, cal.theta[0], cal.theta_std[0]

    return {"spec": spec, "B": B, "J": J, "K": K, "truth": truth, "with": fit(NOISE_M), "without": fit(0.0)}


def test_the_prior_holds_a_weakly_identified_combination_and_leaves_a_well_identified_one(case):
    J, K = case["J"], case["K"]
    t, th, sd = case["with"]
    _, th0, sd0 = case["without"]
    assert K == 10 and t.prior() is not None and case["without"][0].prior()[1].max() == 0.0  # noise 0: no rows
    # the weakest combination: the data alone leave it several prior standard deviations wide and
    # it wanders; with the prior it stays within one of the prior's centre
    weak = J + K - 1
    assert sd0[weak] > 1.2 and abs(th0[weak]) > 1.0
    assert sd[weak] < 0.8 and abs(th[weak]) < 0.5
    # the best determined one (the data's spread a tenth of the prior's): as without the prior, and right
    well = J + int(np.argmin(sd0[J:]))
    assert sd0[well] < 0.1
    assert abs(th[well] - th0[well]) < 0.25 * sd0[well]
    assert abs(th[well] - case["truth"][well - J]) < 3 * sd[well]
    # the one set away from the prior, fairly well determined: found
    assert abs(th[J + 2] - 0.5) < 3 * sd[J + 2] and sd[J + 2] < 0.25


def test_the_report_says_what_the_data_determine_beyond_the_prior(case):
    J, K = case["J"], case["K"]
    t, th, sd = case["with"]
    stored = t.to_dict(th, sd)
    said = stored["where"]["mass_prior"]
    assert said["noise_m"] == NOISE_M and said["prior_std"] == 1.0
    assert np.allclose(said["posterior_std"], sd[J:], atol=1e-4)
    assert said["determined_by_data"] == int(np.sum(sd[J:] < DETERMINED))
    assert 0 < said["determined_by_data"] < K  # the weakest is the prior's, not the data's
    assert said["posterior_std"][-1] > DETERMINED
    assert all(u == "prior standard deviations" for u in t.units[J:])
    # read back: the same prior
    back = Compliance().from_dict(stored)
    assert back.noise_m == NOISE_M and np.allclose(back.prior()[1], t.prior()[1])


def test_a_negative_mass_the_data_determine_is_said(case):
    t, th, _ = case["with"]
    J, K, B = case["J"], case["K"], case["B"]
    T = tree_stand(case["spec"]).loads
    pi0 = T.mass_moments().reshape(-1, 4)
    rows = B.reshape(-1, 4, K)[:, 0, :]  # each body's mass per combination
    j = int(np.argmax(np.linalg.norm(rows, axis=1)))
    delta = -(pi0[j, 0] + 1.0) * rows[j] / (rows[j] @ rows[j])  # that body's mass -1 kg
    theta = np.concatenate([th[:J], delta])
    said = t.mass_estimate(theta, np.full(J + K, 0.01))
    assert said["negative_masses_kg"][T.joints[j]][0] == pytest.approx(-1.0, abs=1e-6)
    assert not said["physical"]
    # the same estimate with the data's spread wide: not said (not determined)
    assert T.joints[j] not in t.mass_estimate(theta, np.full(J + K, 10.0))["negative_masses_kg"]
    # at the prior: physical
    assert t.mass_estimate(np.concatenate([th[:J], np.zeros(K)]), np.full(J + K, 0.01))["physical"]
