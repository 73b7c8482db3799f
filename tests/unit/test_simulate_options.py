"""simulate()'s choices grouped in typed options (platkit.simulate.options): the grouped call and
the flat keyword call are the same simulation, bit for bit."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from platkit.plugins import get_platform
from platkit.simulate import (
    PlanOptions,
    RecordingOptions,
    SimulateKeywords,
    SimulationOptions,
    TruthOptions,
    options_from_keywords,
    simulate,
)
from platkit.simulate.options import KEYWORD_FIELDS


@pytest.fixture(scope="module")
def stewart():
    return get_platform("stewart")


def _same(a, b):
    np.testing.assert_array_equal(a.poses.markers, b.poses.markers)
    np.testing.assert_array_equal(a.poses.controls, b.poses.controls)
    np.testing.assert_array_equal(a.truth.td, b.truth.td)
    np.testing.assert_array_equal(a.truth.mocap_from_base, b.truth.mocap_from_base)
    for x, y in ((a.markers, b.markers), (a.bodies, b.bodies), (a.base_markers, b.base_markers),
                 (a.poses.bodies, b.poses.bodies), (a.poses.base_markers, b.poses.base_markers)):
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_array_equal(x, y)
    assert a.plan_info == b.plan_info


@pytest.mark.parametrize("raw", [True, False])
def test_grouped_options_and_keywords_are_the_same_simulation(stewart, raw):
    flat = simulate(stewart, seed=3, n_poses=10, noise_mm=0.3, occlusion=0.05, n_base_markers=2, n_bodies=1,
                    effects=[("base_tilt", None)], hold_s=2.0, perturbation=1.5, raw=raw)
    grouped = simulate(stewart, SimulationOptions(
        seed=3, raw=raw, plan=PlanOptions(n_poses=10), truth=TruthOptions(perturbation=1.5, effects=[("base_tilt", None)]),
        recording=RecordingOptions(noise_mm=0.3, occlusion=0.05, n_base_markers=2, n_bodies=1, hold_s=2.0)))
    _same(flat, grouped)
    assert [t.effect for t, _ in flat.truth.terms] == [t.effect for t, _ in grouped.truth.terms] == ["base_tilt"]
    assert flat.poses.bodies.shape[1] == 1 and flat.truth.base_markers.shape == (2, 3)


def test_every_keyword_is_a_field_of_one_group():
    assert set(KEYWORD_FIELDS) == set(SimulateKeywords.__annotations__)
    assert len(KEYWORD_FIELDS) == 21  # simulate(spec, ...) took 21 keywords before the grouping
    base = SimulationOptions()
    for key, (group, name) in KEYWORD_FIELDS.items():
        holder = getattr(base, group) if group else base
        assert name in {f.name for f in dataclasses.fields(holder)}, key


def test_keywords_change_only_their_fields_of_given_options():
    base = SimulationOptions(seed=5, recording=RecordingOptions(noise_mm=0.5, n_markers=4), plan=PlanOptions(n_poses=7))
    opts = options_from_keywords(base, noise_mm=0.1, settle_options=None, n_poses=9)
    assert opts.recording == RecordingOptions(noise_mm=0.1, n_markers=4)
    assert opts.plan == PlanOptions(n_poses=9) and opts.seed == 5 and opts.settle is None
    assert base.recording.noise_mm == 0.5  # the options given are not changed


def test_an_unknown_keyword_is_named(stewart):
    with pytest.raises(TypeError, match="unexpected keyword argument 'noise'"):
        simulate(stewart, noise=0.1)
