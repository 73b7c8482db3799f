"""Generic kinematics of any registered stand, derived from its CasADi residual.

Forward kinematics solves G(p) = F(u, td, pose(p)) = 0 for the pose coordinates p by Newton's
method; where the stand has more rows than coordinates it takes the least-squares pose
(Levenberg-Marquardt, rows weighted by their declared plausible misfit) and reports the rows'
misfit. A solve that fails, leaves the stand's branch or misfits beyond the plausible starts
again from a library of poses spread over the stand's free space. Inverse kinematics
uses the stand's closed form where it has one, else Gauss-Newton over u. Velocities and
accelerations come from differentiating the constraint along a motion.

One concept per module, joined in :class:`PlatformModel`:

    core.py          the residual as CasADi functions, strokes, control checks, pose coordinates
    newton.py        the Newton iteration: compiled C (platkit/native.py) or numpy
    forward.py       forward kinematics, one control vector or a batch; misfit, restarts, angles wrapped
    sampling.py      samples of the free space (controls or poses), the start library
    inverse.py       inverse kinematics: closed form, Gauss-Newton, bounded least squares
    rates.py         velocities and accelerations, in pose coordinates or as a twist
    conditioning.py  the velocity Jacobian, condition numbers, distance to a singularity
    results.py       ForwardResult, ForwardBatch, Conditioning
"""
from __future__ import annotations

import threading

from platkit.kinematics.conditioning import SingularityAnalysis
from platkit.kinematics.results import Conditioning, ForwardBatch, ForwardResult
from platkit.model import PlatformSpec

__all__ = ["PlatformModel", "ForwardResult", "ForwardBatch", "Conditioning", "platform_model"]


class PlatformModel(SingularityAnalysis):
    """Numeric solvers for one stand; all Jacobians come from the stand's CasADi functions.

    ``length_unit`` is only the unit in which error messages show lengths ('mm' or 'm').
    ``compile``: False forces the numpy/CasADi Newton (no C compiler involved).
    Instances are not meant to be shared between threads.
    """


#: the models platform_model built, per thread: {id(spec): (spec, model)}
_MODELS = threading.local()
#: the specs whose models are kept per thread; past it the cache starts again
MODELS_KEPT = 16


def platform_model(spec: PlatformSpec) -> PlatformModel:
    """The kinematic model of ``spec``, built once per spec object and thread (building one
    compiles CasADi functions; a model is not shared between threads): what an effect or a
    plugin that needs forward kinematics in every call takes rather than a new PlatformModel."""
    models = getattr(_MODELS, "models", None)
    if models is None:
        models = _MODELS.models = {}
    hit = models.get(id(spec))
    if hit is None or hit[0] is not spec:
        if len(models) > MODELS_KEPT:
            models.clear()
        hit = models[id(spec)] = (spec, PlatformModel(spec))
    return hit[1]
