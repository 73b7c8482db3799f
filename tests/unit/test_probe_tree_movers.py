"""On a tree the marker probe reads each marker's own controls: the joints that move the link it
rides on (a joint off the path from the base to that link cannot bend its mount); on a chain it
is the probe it always was. The rigid registration kept by its inputs during a model selection
returns what computing it again returns. A fit's held-out channels are reused only while its held-out errors are theirs.

The tree is tests/data/trees/two_arm_torso.urdf (a torso yaw and pitch with a coupled second
pitch, a head that moves no marker, two 3-joint arms)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from platkit.calibrate import registration
from platkit.diagnose import fitting
from platkit.diagnose.probes import link_movers, marker_probe
from platkit.plugins import get_platform
from platkit.poses import PoseSet

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
MAPPING = {"R1": "right_tcp", "R2": "right_tcp", "L1": "left_tcp", "L2": "left_tcp", "L3": "left_tcp"}


def _poses(spec, n, mapping=None, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = spec.control_bounds()
    names = list(mapping or ["a", "b", "c"])
    return PoseSet("urdf", rng.uniform(0.8 * lo, 0.8 * hi, (n, spec.n_u)), np.zeros((n, len(names), 3)), names,
                   moving_link=mapping)


def test_each_marker_reads_only_the_controls_of_the_joints_that_move_its_link():
    spec = get_platform("urdf", URDF, moving_link=MAPPING)
    poses = _poses(spec, 60, MAPPING)
    probe = marker_probe(poses, spec)
    assert probe is not None and "move its link" in probe.where["markers"]
    for marker, link in MAPPING.items():
        own = get_platform("urdf", URDF, moving_link=link).control_names  # the link's own chain's joints
        expected = [f"u{spec.control_names.index(n) + 1}" for n in own] + ["reach"]
        got = [p.split("_", 2)[2] for p in probe.parameter_names if p.startswith(f"{marker}_x_")]
        assert got == expected
        assert "head_yaw" not in own and f"u{spec.control_names.index('head_yaw') + 1}" not in got
    assert len(probe.initial) == 3 * (2 * 6 + 3 * 6)  # torso yaw, pitch, 3 arm joints and reach a marker
    # the offset is linear in theta through the Jacobian's columns, each marker its own block
    theta = np.random.default_rng(1).normal(0, 1e-3, len(probe.initial))
    d_m = probe.offset_jacobians(theta, poses, spec.n_u, None, None)[2]
    np.testing.assert_allclose(np.einsum("nmak,k->nma", d_m, theta), probe.marker_offset(theta, poses),
                               rtol=0, atol=1e-15)
    k = 0
    for m, c in enumerate(link_movers(spec, poses)):
        block = d_m[:, m, :, k:k + 3 * (len(c) + 1)]
        assert np.count_nonzero(d_m[:, m]) == np.count_nonzero(block)  # nothing outside its own block
        k += 3 * (len(c) + 1)
    # reach: the mean square of the marker's own controls only (head_yaw moved alone changes nothing)
    moved = poses.subset(np.arange(60))
    moved.controls[:, spec.control_names.index("head_yaw")] *= -0.5
    np.testing.assert_array_equal(probe.marker_offset(theta, moved), probe.marker_offset(theta, poses))


def test_fewer_columns_let_a_smaller_session_have_the_probe():
    spec = get_platform("urdf", URDF, moving_link=MAPPING)
    poses = _poses(spec, 30, MAPPING)  # 10 features a marker without the tree, 6 with it
    assert marker_probe(poses) is None
    assert marker_probe(poses, spec) is not None


def test_a_chain_keeps_every_control_for_every_marker_as_before():
    spec = get_platform("urdf", URDF, moving_link="left_tcp")
    poses = _poses(spec, 60)
    assert link_movers(spec, poses) is None
    plain, with_spec = marker_probe(poses), marker_probe(poses, spec)
    assert with_spec.movers is None and with_spec.where == plain.where
    assert with_spec.parameter_names == plain.parameter_names and len(plain.initial) == 3 * 3 * (spec.n_u + 1)
    theta = np.random.default_rng(2).normal(0, 1e-3, len(plain.initial))
    np.testing.assert_array_equal(with_spec.marker_offset(theta, poses), plain.marker_offset(theta, poses))
    for a, b in zip(with_spec.offset_jacobians(theta, poses, spec.n_u, None, None),
                    plain.offset_jacobians(theta, poses, spec.n_u, None, None)):
        assert (a is None and b is None) or np.array_equal(a, b)


def test_a_kept_registration_is_what_computing_it_again_gives_and_cannot_be_changed_by_its_user():
    rng = np.random.default_rng(4)
    N, M = 40, 3
    R = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(N)])
    R *= np.sign(np.linalg.det(R))[:, None, None]
    X = rng.normal(0, 0.3, (N, 3))
    A_true = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    A_true *= np.sign(np.linalg.det(A_true))
    m = rng.normal(0, 0.05, (M, 3))
    Y = (X[:, None] + np.einsum("nab,mb->nma", R, m)) @ A_true.T + [0.1, 0.2, 0.3] + rng.normal(0, 1e-5, (N, M, 3))
    vis = np.ones((N, M), bool)
    vis[3, 1] = False
    fresh = registration.register(R[:, None], X[:, None], Y, vis, registration.initial_rotation(R, X, Y, vis))
    args = (R[:, None], X[:, None], Y, vis, (R, X, Y, vis))
    registration.registered(*args)
    assert not registration._KEPT  # outside a selection nothing is kept
    with registration.kept_registrations():
        first = registration.registered(*args)
        assert len(registration._KEPT) == 1
        for a in first:
            a[...] = 7.0  # the user writes into what it got
        with registration.kept_registrations():  # a selection inside another
            again = registration.registered(*args)
        assert len(registration._KEPT) == 1  # kept, not computed again
        for a, b in zip(fresh, again):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_allclose(again[0], A_true, atol=1e-4)
        Y2 = Y.copy()
        Y2[0, 0, 0] += 1e-3  # other inputs: computed, not the kept result
        other = registration.registered(R[:, None], X[:, None], Y2, vis, (R, X, Y2, vis))
        assert len(registration._KEPT) == 2 and not np.array_equal(other[2], again[2])
    assert not registration._KEPT  # forgotten when the selection is over


def test_a_fits_held_out_channels_are_kept_only_while_its_held_out_errors_are_theirs(monkeypatch):
    calls = []

    def channels(fit, spec, poses, folds, iterations):
        calls.append((folds, iterations))
        return np.full((4, 2), float(len(calls)))

    monkeypatch.setattr(fitting, "_cv_channels", channels)
    poses = PoseSet("x", np.zeros((4, 1)), np.zeros((4, 2, 3)), ["a", "b"])
    fit = fitting.Fit([], None, np.zeros(1), np.ones(1, bool), np.ones((4, 2)), np.zeros((4, 2, 3)), 0.0, 24, 1)
    assert fitting._kept_channels(fit, poses, 5, 10) is None  # no held-out errors yet
    fit.cv = fitting._cv(fit, None, poses, 5, 10)
    assert fitting._kept_channels(fit, poses, 5, 10)[0, 0] == 1.0 and len(calls) == 1
    assert fitting._kept_channels(fit, poses, 4, 10) is None  # other folds
    assert fitting._kept_channels(fit, poses, 5, 9) is None  # other iterations
    assert fitting._kept_channels(fit, poses.subset(np.arange(4)), 5, 10) is None  # other poses
    fit.cv = fit.cv.copy()  # held-out errors set from elsewhere: the kept channels are not theirs
    assert fitting._kept_channels(fit, poses, 5, 10) is None


def test_markers_on_one_link_share_their_features():
    spec = get_platform("urdf", URDF, moving_link=MAPPING)
    poses = _poses(spec, 60, MAPPING)
    feats = marker_probe(poses, spec).marker_features(poses)  # R1, R2, L1, L2, L3
    assert feats[0] is feats[1] and feats[2] is feats[3] is feats[4] and feats[0] is not feats[2]
