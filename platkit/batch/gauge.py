"""One parameterisation for every session of a fleet or a history, so their estimates compare.

A calibration holds at nominal the stand parameters its data cannot fix, chosen by pivoting on
the session's own identification Jacobian (platkit.calibrate.identifiability.select_identifiable).
Where the stand has a symmetry (a gauge: moving every base joint with the motion-capture frame
changes no marker), *which* of the parameters in it is held then depends on the session's poses,
markers and noise, and so do the values of the others: two sessions of one unchanged stand give
estimates in two gauges, and their difference is no change of the stand.

A batch therefore fixes the parameterisation once, before any session is calibrated:

- the free parameters: those of ``--free`` (names or groups), of a reference calibration's
  estimates (``--reference calibration.yaml``: its ``estimated`` parameters), or the stand's
  default free set;
- less the gauge: the free parameters that no set of poses the stand can take fixes, chosen by
  the very same pivoting (select_identifiable, with calibrate's tiers and scales) on the stand's
  reference poses (platkit.calibrate.plan.reference_poses_for, those calibrate and plan judge
  gauges on), with the base-to-motion-capture transform and the markers estimated first. These
  are held at nominal in every session; what they stand for is carried by the others, the same
  way in every session.

Every session is then calibrated with exactly the free list that remains (no per-session model
selection, which would choose other groups in other sessions). A parameter of the list that a
session's poses do not excite is held in that session alone and reported as not identified
there (its status in calibration.yaml), never compared as a value.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from platkit.calibrate.identifiability import DEFAULT_REL_TOL, select_identifiable
from platkit.calibrate.plan import default_marker_layout, identification_jacobian, reference_poses_for
from platkit.calibrate.stages import free_mask
from platkit.errors import BadInput
from platkit.model import PlatformSpec

__all__ = ["Parameterisation", "common_parameterisation", "reference_free"]

#: markers of the layout the reference Jacobian is taken with (plan's default layout, seed 0)
REFERENCE_MARKERS = 5


@dataclass
class Parameterisation:
    """The parameterisation of a batch: ``free`` the parameter names every session estimates,
    ``gauge`` those of the requested set held at nominal in every session (no pose fixes them:
    ``{name: the combination of estimated parameters it trades against}``), ``decided_by`` how
    the free set was chosen (one line)."""

    stand: str
    free: list[str]
    gauge: dict[str, dict[str, float]] = field(default_factory=dict)
    decided_by: str = ""

    def to_dict(self) -> dict:
        return {"stand": self.stand, "free": list(self.free), "gauge_held": {k: dict(v) for k, v in self.gauge.items()},
                "decided_by": self.decided_by,
                "rule": "every session is calibrated with exactly these free parameters; the gauge-held ones are at "
                        "nominal in every session (chosen once, on the stand's reference poses)"}


def reference_free(path: str | Path, spec: PlatformSpec) -> list[str]:
    """The parameters a reference calibration estimated (status 'estimated' in its
    calibration.yaml), in the stand's order. Bad input naming the file when it is not a
    calibration of this stand or estimates nothing."""
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise BadInput(f"--reference {p}: cannot read it as a calibration.yaml ({exc})") from None
    params = data.get("parameters") if isinstance(data, dict) else None
    if not isinstance(params, dict):
        raise BadInput(f"--reference {p}: no 'parameters' mapping; give a calibration.yaml written by platkit calibrate")
    if data.get("platform") not in (None, spec.name):
        raise BadInput(f"--reference {p}: a calibration of the {data.get('platform')} stand, the sessions are "
                       f"{spec.name}")
    known = set(spec.parameter_names)
    unknown = sorted(set(params) - known)
    if unknown:
        raise BadInput(f"--reference {p}: parameters {', '.join(unknown[:3])} are not the {spec.name} stand's")
    estimated = {n for n, e in params.items() if isinstance(e, dict) and e.get("status") == "estimated"}
    if not estimated:
        raise BadInput(f"--reference {p}: estimates no stand parameter (status 'estimated'); nothing to compare on")
    return [n for n in spec.parameter_names if n in estimated]


def common_parameterisation(spec: PlatformSpec, free: Sequence[str] | None = None, decided_by: str = "",
                            rel_tol: float = DEFAULT_REL_TOL) -> Parameterisation:
    """The batch's parameterisation (module docstring) for ``free`` (names or groups as
    ``--free`` takes them; None: the stand's default free parameters)."""
    mask = free_mask(spec, free)
    wanted = [p.name for p, f in zip(spec.parameters, mask) if f]
    if not wanted:
        return Parameterisation(spec.name, [], {}, decided_by)
    # the Jacobian over the requested parameters, whether or not the stand frees them by default
    every = dataclasses.replace(spec, parameters=[dataclasses.replace(p, free=p.name in wanted)
                                                  for p in spec.parameters])
    U_ref, P_ref = reference_poses_for(every)
    markers = default_marker_layout(every, REFERENCE_MARKERS, np.random.default_rng(0))
    ij = identification_jacobian(every, U_ref, markers, P=P_ref)
    n = len(ij.names)
    scale = np.array([1e-3 if u in ("m", "rad", "1", "") else 1.0 for u in ij.units])
    tiers = [1] * ij.n_td + [0] * (n - ij.n_td)  # the transform and markers first, as calibrate
    ident = select_identifiable(ij.J.reshape(-1, n), ij.names, scale, tiers, rel_tol)
    held = {h.name: {k: float(v) for k, v in h.combination.items() if k != h.name}
            for h in ident.held if h.name in wanted}
    return Parameterisation(spec.name, [n_ for n_ in wanted if n_ not in held], held, decided_by)
