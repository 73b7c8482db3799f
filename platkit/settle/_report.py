"""What the settling search says (platkit.settle): its options, its report, and the
dropped commands and settling summary that report.json carries."""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from platkit.model import length_scale
from platkit.poses import PoseSet

#: the categories a dropped command's reason starts with (``category: detail``)
DROP_CATEGORIES = ("no motion-capture samples", "too few samples", "moved again", "never settled",
                   "every marker occluded")


@dataclass
class SettleOptions:
    """Tuning of the settling search. Times in seconds."""

    window_s: float = 0.1  # length of each half of the stillness test
    min_still_s: float = 0.25  # a pose needs the platform still at least this long
    false_alarm: float = 1e-4  # probability a still sample is called moving
    gap_samples: int = 2  # moving samples tolerated inside a still stretch
    end_slack_s: float = 0.2  # the still stretch may end this long before the next command
                              # (motion starting early: a clock offset between the two files)
    sigma_m: float | None = None  # marker noise per coordinate; None: estimated
    tail_fraction: float = 0.05  # the approach's tail may bias a window mean by this much of its noise
    trend_false_alarm: float = 1e-3  # probability a still window is called trending
    max_unsettled_fraction: float = 0.1  # beyond: unsettled holds are extrapolated to rest (or the search stops)
    extrapolate: str = "auto"  # 'auto' (beyond max_unsettled_fraction), 'always', 'never'
    # an approach is extrapolated to rest only this far (m): markers follow the actuators through
    # the kinematics, and beyond about a millimetre the path to rest bends away from the fitted decay
    max_extrapolation_m: float = 1e-3
    # ... or this share of the hold's step (largest marker): over a small share of a move the
    # kinematics are straight whatever the stand's size
    max_extrapolation_share: float = 0.02
    # the window is at most this long, ending where the hold does (None: no limit). The early part
    # of a long still stretch is where a slow approach's last tail hides below the stillness test,
    # and with coloured marker noise averaging it gains little: on the physical simulator's psvr
    # (dev seeds 700300-700329, 60 commands) the noise-free tail left in the window means went
    # from -0.030 to -0.009 of a pose's averaging noise, that noise from 12.2 to 12.3 um
    max_window_s: float | None = 1.5
    bound_keeps: float = 0.4  # the tail's upper bound may cut the still stretch to this share (else its estimate rules)
    # ... or to this share when the still stretches of the session, pooled, bear out their fitted
    # tails (regressed on them: kappa at least tail_evidence_z standard errors above zero)
    bound_keeps_evident: float = 0.25
    tail_evidence_z: float = 3.0


@dataclass
class SettleReport:
    """What the settling search found, for the person reading the calibration report.

    dropped: (row, reason) of the commands that gave no pose; ``counts``: reason category -> count;
    unsettled: a summary of the holds that never settled (empty when none), with ``sentence``.
    """

    sigma_m: float
    n_commands: int
    n_kept: int
    dropped: list[tuple[int, str]]
    rate_hz: float
    n_extrapolated: int = 0
    unsettled: dict = field(default_factory=dict)

    @property
    def counts(self) -> dict[str, int]:
        return dropped_by_reason(self.dropped)


def dropped_by_reason(dropped: list[tuple[int, str]]) -> dict[str, int]:
    """Reason category (the text before the first ':') -> number of dropped commands, largest first."""
    c = Counter(str(why).split(":", 1)[0].strip() for _, why in dropped)
    return dict(sorted(c.items(), key=lambda kv: -kv[1]))


def dropped_sentence(dropped: list[tuple[int, str]], n_commands: int | None = None) -> str:
    """One line: how many commands were dropped, by reason ('' when none)."""
    if not dropped:
        return ""
    of = f" of {n_commands}" if n_commands is not None else ""
    parts = ", ".join(f"{n} {why}" for why, n in dropped_by_reason(dropped).items())
    return f"{len(dropped)}{of} commands gave no settled pose: {parts}"


def settling_summary(poses: PoseSet, unit: str | None = None) -> dict:
    """What became of every command of a session, for report.json (lengths in ``unit``, default
    the session's): n_commands, n_poses, n_dropped, dropped_by_reason, dropped (row: 1-based data
    row of commands.csv, reason), n_extrapolated and, when holds never settled, ``unsettled``
    (sentence, actuators, markers, time_constant_s, hold_s, remaining, moved_late_along_actuator:
    per actuator, the median over its holds of how far the markers still moved along its own
    Jacobian column late in the hold, reversed; positive: behind its command)."""
    scale = length_scale(unit or poses.length_unit)
    info = poses.settling or {}
    n_commands = int(info.get("n_commands", poses.n_poses + len(poses.dropped)))
    out = {"n_commands": n_commands, "n_poses": int(poses.n_poses), "n_dropped": len(poses.dropped),
           "dropped_by_reason": dropped_by_reason(poses.dropped),
           "dropped": [{"row": int(r) + 1, "reason": str(why)} for r, why in poses.dropped],
           "n_extrapolated": int(info.get("n_extrapolated", 0))}
    un = info.get("unsettled") or {}
    if un:
        out["unsettled"] = {"sentence": un["sentence"], "n": int(un["n"]), "actuators": list(un["actuators"]),
                            "markers": list(un["markers"]),
                            "time_constant_s": _finite(un["time_constant_s"]),
                            "time_constant_quartiles_s": [_finite(v) for v in un["time_constant_quartiles_s"]],
                            "hold_s": _finite(un["hold_s"]), "remaining": _finite(un["remaining_m"] / scale),
                            "moved_late_along_actuator": {
                                k: (None if v is None else v / scale)
                                for k, v in (un.get("moved_late_along_actuator_m") or {}).items()}}
    return out


def _finite(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None
