"""A re-registered held-out stream's verdict is tested over its windows, as the held-out stream's is."""
from types import SimpleNamespace

import numpy as np

import platkit.diagnose.registered as registered
from platkit.calibrate.stream import NODES
from platkit.diagnose.stats import paired_improvement


def _scores(per_pose):
    one = SimpleNamespace(shift=lambda cal: (0.0, 0.0), n_rejected=0)
    return SimpleNamespace(per_pose=lambda: per_pose, rms=0.0, names=[], registrations=[one], blocks=[0],
                           rms_of=lambda name: 0.0)


def test_a_registered_stream_is_paired_over_its_windows(monkeypatch):
    rng = np.random.default_rng(7)
    n_windows = 12
    node = np.arange(n_windows * NODES)
    # each window's poses lean the same way: independent poses would read three times the evidence
    lean = np.repeat(rng.normal(0.3, 1.0, n_windows), NODES) + 0.1 * rng.normal(size=node.size)
    before, after = 2.0 + lean, np.full(node.size, 2.0)
    scores = iter([_scores(before), _scores(after)])
    monkeypatch.setattr(registered, "rotated_scores", lambda *a, **k: next(scores))
    held = SimpleNamespace(extras={"node": node})
    h = registered.registered_heldout(None, SimpleNamespace(), held, 3)
    windowed = paired_improvement(before, after, node // NODES)
    assert h["p_improvement"] == windowed
    assert windowed > 2 * paired_improvement(before, after)
