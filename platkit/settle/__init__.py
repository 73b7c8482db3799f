"""Settling: settled poses from raw motion-capture streams, the stage below calibrate, diagnose and simulate.

The public face: :func:`settle` (a session -> PoseSet and SettleReport), :func:`load_poses` (a session
folder -> the PoseSet every estimator takes), the options and report, and the few stream tools that
diagnosis and simulation reuse. The search itself lives in the private modules: ``_still`` (the
stillness test and noise), ``_approach`` (the fitted approach to rest), ``_fits`` (the approach fits,
many holds at once), ``_tail`` (the tail the holds share), ``_unsettled`` and ``_attribution`` (what a
session that never settles is said to be), and ``_report`` (options, report, the dropped rows said).
"""
from platkit.settle._approach import Approach
from platkit.settle._attribution import attribute_actuators
from platkit.settle._fits import fit_approach
from platkit.settle._report import (
    DROP_CATEGORIES,
    SettleOptions,
    SettleReport,
    dropped_by_reason,
    dropped_sentence,
    settling_summary,
)
from platkit.settle._settle import SLOW_SCALE_S, HoldsNeverSettle, NeverSettles, load_poses, poses_from_table, settle
from platkit.settle._still import direction_of_last_motion, estimate_noise, last_step, still_mask, trend_test
from platkit.settle._unsettled import refusal

__all__ = [
    "DROP_CATEGORIES", "SLOW_SCALE_S", "Approach", "HoldsNeverSettle", "NeverSettles", "SettleOptions", "SettleReport",
    "attribute_actuators",
    "direction_of_last_motion", "dropped_by_reason", "dropped_sentence", "estimate_noise", "fit_approach",
    "last_step", "load_poses", "poses_from_table", "refusal", "settle", "settling_summary", "still_mask", "trend_test",
]
