"""The search chooses an accepted term's variant again once a later term is accepted
(Search.variants_again, after each acceptance): a thermal drift whose cooling time constant was
chosen in round 1 far from the truth (forced here, as a large effect still in the residual can
pull it) is chosen again beside the backlash named in round 2, and the finding, the model and
the round's record all carry the new one."""
from __future__ import annotations

import numpy as np
import pytest

import platkit.diagnose.search as search_mod
from platkit.diagnose.fitting import _fit
from platkit.diagnose.search import diagnose
from platkit.effects import with_history
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.simulate.physics import simulate_physics


@pytest.fixture(scope="module")
def session():
    """A stewart's settled poses: a strong thermal drift (heat from work, named first) and a
    smaller backlash, a little noise."""
    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=5190001, n_poses=60, plan="random",
                           effects=[("backlash", 0.3), ("thermal_drift", 1.0)])
    noisy = sim.settled_markers + np.random.default_rng(1).normal(0, 2e-5, sim.settled_markers.shape)
    poses = with_history(PoseSet(spec.name, sim.commands, noisy, list(sim.marker_names), t=sim.command_t,
                                 length_unit=sim.length_unit, source="test"), spec)
    tau = next(p.parameters()["cooling_time_constant_s"] for name, p in sim.physics if name == "thermal_drift")
    return spec, poses, tau


def test_a_variant_chosen_far_in_its_round_is_chosen_again_after_the_next(session, monkeypatch):
    spec, poses, tau = session
    real = search_mod.best_variant

    def far(i0, cands, scr, cur, spec, poses, weights, opt):
        """Round 1's thermal drift at the variant nearest 4 times the true time constant."""
        if cands[i0][0].name != "thermal_drift" or any(t.effect == "thermal_drift" for t in cur.terms):
            return real(i0, cands, scr, cur, spec, poses, weights, opt)
        heat = [j for j, (e, t) in enumerate(cands) if e.name == "thermal_drift" and t.where.get("form") == "heat from work"]
        j = min(heat, key=lambda j: abs(np.log(cands[j][1].where["cooling_time_constant_s"] / (4 * tau))))
        return j, _fit(spec, poses, cur.terms + [cands[j][1]], cur.z, cur.active, weights, opt.lm_iterations,
                       opt.robust)

    monkeypatch.setattr(search_mod, "best_variant", far)
    d = diagnose(spec, poses)
    assert sorted(f.effect for f in d.findings) == ["backlash", "thermal_drift"]
    heat = next(f for f in d.findings if f.effect == "thermal_drift")
    chosen = heat.where["cooling_time_constant_s"]
    assert abs(np.log(chosen / tau)) < np.log(1.5), (chosen, tau)
    again = [n for r in d.rounds for n in r.get("variants_again", [])]
    assert len(again) == 1 and again[0]["effect"] == "thermal_drift" and again[0]["bic_change"] < -2.0
    before, after = again[0]["changed"]["cooling_time_constant_s"]
    assert abs(np.log(before / (4 * tau))) < np.log(1.5) and after == chosen
    assert heat.term.where["cooling_time_constant_s"] == chosen
