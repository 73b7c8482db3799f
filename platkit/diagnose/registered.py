"""A held-out session scored after re-registration (``platkit diagnose --heldout-register K``).

The held-out session was recorded in a motion-capture set-up of its own (another day: the cameras
calibrated again, the robot moved, the marker body mounted again). Beside the scores of the model
as it is (``heldout_session``'s rms_before and rms_after), the geometric model and the diagnosed
one are each re-registered to that set-up by rotation (:func:`platkit.calibrate.reregister.rotated_scores`:
K consecutive poses fit the base-to-mocap transform, and the marker places where asked, every
other parameter held; the session's other poses are scored; the blocks rotate so that every pose
is scored). The two models' per-pose errors are paired as the held-out ones are (one-sided
Wilcoxon). Never used to choose a model.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from platkit.calibrate.reregister import rotated_scores
from platkit.diagnose.stats import paired_improvement
from platkit.diagnose.stream import windows_of
from platkit.io.calibration import Calibration
from platkit.poses import PoseSet


def registered_heldout(base: Calibration, final: Calibration, heldout: PoseSet, k: int, markers: bool = False,
                       robust: bool = True, spread: bool = False,
                       heldout_after: PoseSet | None = None) -> dict[str, Any]:
    """``heldout`` as ``base`` reads it and ``heldout_after`` as ``final`` does (the same poses and
    markers; a held-out stream's controls through each model's own response,
    platkit.diagnose.stream.read_through; None: ``heldout``) scored as the module says:
    {'k', 'marker_places_refitted', 'n_registrations', 'rms_before', 'rms_after' (m),
    'per_marker' {name: (before, after) m}, 'p_improvement' (over a stream's windows where
    ``heldout`` is windowed poses: platkit.diagnose.stream.windows_of), 'turn_rad' and 'move' (m): the
    median over the registrations of how far the diagnosed model's transform moved from its own,
    'n_rejected' points left out as outliers over them, 'spread' whether a block's poses lie across
    the recording}."""
    before = rotated_scores(base, heldout, k, markers, robust=robust, spread=spread)
    after = rotated_scores(final, heldout if heldout_after is None else heldout_after, k, markers, robust=robust,
                           spread=spread)
    shifts = np.array([r.shift(final) for r in after.registrations])
    return {"k": int(k), "marker_places_refitted": bool(markers), "spread": bool(spread),
            "n_registrations": len(after.blocks),
            "rms_before": before.rms, "rms_after": after.rms,
            "per_marker": {n: (before.rms_of(n), after.rms_of(n)) for n in after.names},
            "p_improvement": paired_improvement(before.per_pose(), after.per_pose(),
                                                windows_of(heldout) if "node" in heldout.extras else None),
            "turn_rad": float(np.median(shifts[:, 0])), "move": float(np.median(shifts[:, 1])),
            "n_rejected": int(sum(r.n_rejected for r in after.registrations))}


def registered_in_unit(h: dict[str, Any], scale: float) -> dict[str, Any]:
    """diagnosis.json's ``heldout_session.registered``: lengths divided by ``scale`` (m per unit)."""

    def num(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    return {"k": h["k"], "marker_places_refitted": h["marker_places_refitted"], "spread": h["spread"],
            "n_registrations": h["n_registrations"], "rms_before": num(h["rms_before"] / scale),
            "rms_after": num(h["rms_after"] / scale), "p_improvement": num(h["p_improvement"]),
            "per_marker": {n: [num(a / scale), num(b / scale)] for n, (a, b) in h["per_marker"].items()},
            "median_turn_from_calibration_rad": num(h["turn_rad"]),
            "median_move_from_calibration": num(h["move"] / scale), "n_rejected_as_outliers": h["n_rejected"],
            "protocol": (f"blocks of {h['k']} "
                         + ("poses taken across the recording" if h["spread"] else "consecutive poses")
                         + " re-register the base-to-mocap transform"
                         + (" and the marker places" if h["marker_places_refitted"] else "")
                         + ", every other parameter held; the session's other poses are scored; the blocks rotate so "
                           "that every pose is scored, a pose's error the mean over its scorings")}


__all__ = ["registered_heldout", "registered_in_unit"]
