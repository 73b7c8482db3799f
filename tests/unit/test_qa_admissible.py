"""The admissible set of a long chain: the control box is sampled within a fixed budget (before:
7**8 = 5.8 million forward solutions for TIAGo's arm, and over 13 GB of memory)."""
from pathlib import Path

import numpy as np

from platkit import admissible
from platkit.plugins import get_platform

TIAGO = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "tiago" / "tiago_48_schunk.urdf"
if not TIAGO.is_file():  # the checkout beside shared/, as CI has it
    TIAGO = Path("/work/shared/data/real/tiago/tiago_48_schunk.urdf")


def test_long_chains_get_the_finest_grid_within_the_budget():
    spec = get_platform("urdf", TIAGO, moving_link="wrist_ft_tool_link")
    U = admissible.control_samples(spec, 7)
    assert spec.n_u == 8
    assert U.shape == (3 ** 8, 8)  # 3**8 = 6561 <= 20000 < 4**8
    lo, hi = spec.control_bounds()
    assert np.all(U >= lo) and np.all(U <= hi)
    assert np.allclose(U.min(axis=0), lo) and np.allclose(U.max(axis=0), hi)


def test_the_budget_falls_back_to_seeded_draws_when_even_the_corners_do_not_fit():
    spec = get_platform("urdf", TIAGO, moving_link="wrist_ft_tool_link")
    U = admissible.control_samples(spec, 7, max_samples=100)  # 2**8 = 256 corners > 100
    assert U.shape == (100, 8)
    np.testing.assert_array_equal(U, admissible.control_samples(spec, 7, max_samples=100))


def test_short_stands_keep_the_full_grid():
    spec = get_platform("psvr")
    assert admissible.control_samples(spec, 7).shape == (7 ** 3, 3)


def test_pose_images_of_tiago_use_the_budget(monkeypatch):
    spec = get_platform("urdf", TIAGO, moving_link="wrist_ft_tool_link")
    seen = []
    real = admissible.control_samples
    monkeypatch.setattr(admissible, "control_samples", lambda *a, **k: seen.append(real(*a, **k)) or seen[-1])
    pts = admissible.pose_images(spec, 7)
    assert seen[0].shape[0] == 3 ** 8 and pts.shape[1] == spec.n_p and pts.shape[0] > 0
