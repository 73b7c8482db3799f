"""The samples past the end of a command log cut in motion, in a calibration from motion
(:mod:`platkit.calibrate.motion`, step 2) and in the stream a diagnosis reads
(:func:`platkit.calibrate.motion.motion_stream`): where they begin under a response
(:func:`log_end_at`) and what is said of them (:func:`say_past_log`). The rule
(:func:`platkit.calibrate.stream.past_log_end`): a sample at t reads the commands of t - lag; the
samples that read past the last command and its interval follow commands the log does not have
and are left out; a log that ends at rest (its last steps, or the markers seen still after it)
keeps every sample, its last command held being what the stand was told. calibrate_motion fixes
the set at the response's start (found on every sample) and keeps it through its fits;
motion_stream takes it at the calibration's response."""
from __future__ import annotations

import numpy as np

from platkit.calibrate.motion_transient import settle_time_s
from platkit.calibrate.response import ResponseModel, lags
from platkit.calibrate.stream import past_log_end
from platkit.io.calibration import Calibration
from platkit.io.session import Session

__all__ = ["RULE", "SETTLE_TAUS", "log_end_at", "say_past_log"]

#: the markers judge a stand at rest after its log's end from SETTLE_TAUS times the response's
#: slowest decay on (its response to the last command settled to under 1 %)
SETTLE_TAUS = 5.0
#: the rule in words (the report's samples rule)
RULE = ("past it a sample, read through the response's lag at its start, follows commands the log does not have; "
        "a log that ends at rest keeps every sample")


def log_end_at(session: Session, rmodel: ResponseModel, theta) -> float | None:
    """:func:`platkit.calibrate.stream.past_log_end` under the response ``theta``: its actuators'
    lags, and SETTLE_TAUS times the slowest decay of the actuators the log moves for the response
    to its last command to settle before the markers judge the stand at rest."""
    moved = np.ptp(session.commands, axis=0) > 0
    return past_log_end(session, rmodel.reference, lags(rmodel, theta),
                        SETTLE_TAUS * settle_time_s(rmodel, theta, moved))


def say_past_log(session: Session, n: int, end_t: float | None, cal: Calibration) -> None:
    """The ``n`` samples left out after ``end_t`` (the motion capture's clock), said in a warning of
    ``cal`` (the report's ``motion.samples`` counts them); nothing where none."""
    if n:
        cal.warnings.append(f"{session.folder / 'commands.csv'}: the command log ends in motion (its last command at "
                            f"{session.command_t[-1]:.3f} s): {n} samples after {end_t:.3f} s (the motion capture's "
                            "clock, through the response's lag) follow commands the log does not have, left out "
                            "(report: motion.samples.n_past_the_log)")
