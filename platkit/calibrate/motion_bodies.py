"""Rigid bodies in a calibration from motion (:mod:`platkit.calibrate.motion`): what the fit does
with a session's bodies measured in 6 DOF.

Calibration from motion reduces the stream to nodes of points (:func:`platkit.calibrate.stream.stream_windows`:
each marker coordinate fitted by a polynomial in time per window, corrected for the kinematics'
curvature); a body's orientation has no such reduction here, so the fit from motion reads the
markers alone. Nothing is dropped silently: :func:`unused_bodies` counts the body samples the fit
leaves out (each body seen at a sample is one sample: its origin and orientation), per body, and
says why; the caller puts that in the report (``motion.samples.rigid_bodies_not_used``) and in a
warning. A session with bodies and no markers is refused
(:func:`platkit.calibrate.stream.check_motion_session`).
"""
from __future__ import annotations

import numpy as np

from platkit.io.calibration import Calibration
from platkit.io.session import Session

__all__ = ["unused_bodies", "bodies_warning", "say_unused_bodies"]

#: why the fit from motion leaves the bodies out (said in the report and the warning)
WHY = ("calibration from motion reduces the stream to nodes of points (each marker coordinate fitted by a polynomial "
       "in time per window, corrected for the kinematics' curvature); a body's orientation has no such reduction, so "
       "the fit from motion reads the markers alone; a session whose holds settle calibrates the bodies "
       "(platkit.bodies)")


def unused_bodies(session: Session) -> dict | None:
    """The session's rigid bodies that the fit from motion leaves out: ``{"bodies": names,
    "n_body_samples": body samples in the stream (a body seen at a sample: origin and orientation
    finite), "per_body": {name: samples}, "why": ...}``; None where the session has no bodies."""
    if not session.body_names or session.bodies is None:
        return None
    seen = np.isfinite(np.asarray(session.bodies, float)).all(axis=2)  # (K, B)
    per = {str(b): int(n) for b, n in zip(session.body_names, seen.sum(axis=0))}
    return {"bodies": list(per), "n_body_samples": int(sum(per.values())), "per_body": per, "why": WHY}


def bodies_warning(unused: dict) -> str:
    """The warning line of :func:`unused_bodies`' result."""
    each = ", ".join(f"{b} {n}" for b, n in unused["per_body"].items())
    return (f"rigid bodies {', '.join(unused['bodies'])} not used: {unused['n_body_samples']} body samples ({each}) "
            f"left out of the fit from motion: {unused['why']} (report: motion.samples.rigid_bodies_not_used)")


def say_unused_bodies(session: Session, cal: Calibration) -> None:
    """The session's bodies left out (:func:`unused_bodies`) said in ``cal``: in its report
    (``motion.samples.rigid_bodies_not_used``) and its warnings; nothing where it has none."""
    unused = unused_bodies(session)
    if unused is not None:
        cal.motion.setdefault("samples", {})["rigid_bodies_not_used"] = unused
        cal.warnings.append(bodies_warning(unused))
