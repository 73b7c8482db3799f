"""The heat of a thermal drift when commands gave no pose (held out, never settled): the hidden
commands' path is estimated closely enough that one expansion coefficient and the true cooling
time constant still explain the lengthening (issue 10)."""
import numpy as np

from platkit.effects import with_history
from platkit.poses import PoseSet
from platkit_effects import motion_heat


def _heat_error(seed: int, tau: float, steps: bool = False) -> float:
    """RMS of the gapped session's heat against the full one, over the spread of the full one;
    ``steps``: each row's last step from the full command list kept (as the session reader does)."""
    rng = np.random.default_rng(seed)
    n = 60
    U = rng.uniform(0, 1, (n, 6))  # a random plan, as the proof benchmark's
    t = np.cumsum(rng.uniform(3.4, 4.6, n))
    poses = PoseSet("x", U, np.zeros((n, 3, 3)), ["a", "b", "c"], t=t)
    full = motion_heat(poses, np.ones(6), tau)
    keep = np.arange(n) % 5 != 2  # every fifth command gave no pose
    sub = with_history(poses, None).subset(keep)
    sub.extras = {k: v for k, v in sub.extras.items() if not k.startswith("heat_") and (steps or k != "last_step")}
    y = full[keep]
    h = motion_heat(sub, np.ones(6), tau)
    return float(np.sqrt(np.mean((y - h) ** 2)) / np.sqrt(np.mean((y - y.mean(axis=0)) ** 2)))


def test_a_random_plans_gaps_keep_its_heat():
    # the move across a gap scaled by g m1 / m_gap (the former estimate) lost the path of a hidden
    # command that went out and came back: 0.19-0.26 of the heat's spread on these seeds (mean
    # 0.23), which read tau 1697 s for a true 368 s on a stewart session (seed 708000)
    err = [_heat_error(seed, tau) for seed, tau in enumerate((370.0, 500.0, 310.0, 720.0, 400.0, 600.0))]
    assert max(err) < 0.22 and np.mean(err) < 0.19, err


def test_each_rows_own_last_step_gives_a_one_command_gap_exactly():
    # the session reader keeps each row's step from its true previous command: the hidden command
    # is known, only the decay between it and the row is not (0.12-0.20 of the spread without)
    err = [_heat_error(seed, tau, steps=True) for seed, tau in enumerate((370.0, 500.0, 310.0, 720.0, 400.0, 600.0))]
    assert max(err) < 0.02, err
