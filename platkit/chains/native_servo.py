"""The tracking servo's one-target loop compiled: :meth:`Servo._fast_attempt` in C.

A servo iteration of the Python loop costs 40-76 us of numpy calls on 6-vectors; the
same iteration in C costs a few. The C source below knows no robot: the chain comes in as
arrays (for every joint from the root to the controlled link its placement in the parent joint,
its kind, axis and column in theta; the link's placement in the last joint), so one library
serves every chain. It does what the Python loop does, number for number up to rounding:

* the pose and the LOCAL_WORLD_ALIGNED frame Jacobian by forward kinematics along the joints
  (the quantities pinocchio's ``forwardKinematics`` / ``computeFrameJacobian`` give), the error
  E = (t_U - t_P, log3(R_U R_P^T)) with pinocchio's ``log3`` formula;
* the step of ``Servo._fast_step``: the commanded twist (gain, step caps), the weighted rows, the
  damped pseudo-inverse by SVD (one-sided Jacobi here, LAPACK there) with the ``Damping``
  schedule and the 1e-10 rank cut, a joint that would cross a position limit clamped there and
  the rest re-solved (the worst first, at most n + 1 passes), then the uniform scaling to the
  rate limits and the clip to both bounds;
* the line search (12 halvings, accept below merit (1 - 1e-12)), the tolerance test, the stall
  rule (no 1e-3 fall of the merit in ``stall_iterations`` steps) and the iteration cap.

The loop runs in chunks of at most ``CHUNK`` iterations; the caller checks the time cap between
chunks (a chunk takes well under a millisecond) and words the reasons. The C source is
native_servo.c beside this module (package data); it is compiled once with the system C compiler
into the cache directory (:func:`platkit.native.compiled_library`, keyed by the hash of the
source, the compiler and the flags); without a compiler or with ``PLATKIT_COMPILE=0`` the Python
loop serves.
"""
from __future__ import annotations

import ctypes
import threading
import weakref
from pathlib import Path

import numpy as np

from platkit.chains.chain import KinematicChain
from platkit.io.cache import c_compiler
from platkit.native import c_source, compiled_library

#: iterations per call into C; the time cap is checked between calls
CHUNK = 128
#: the most joints the compiled loop takes (its work arrays live on the C stack)
MAX_JOINTS = 64

#: what a chunk ended with (the C function's return value)
CONVERGED, LINE_SEARCH_FAILED, STALLED, ITERATION_CAP, TIME_CAP, CHUNK_DONE = 0, 1, 2, 3, 4, 5

# ints: n, nj, max_iterations, stall_iterations, use_rate_limits, has_error_scale, then
#       active (n), column (nj), kind (nj: 0/1/2 revolute about x/y/z, 3 revolute about an axis, 4 prismatic)
# doubles: gain, max_linear_step, max_angular_step, damping threshold, max damping, error scale,
#          tol_position, tol_rotation, weights (6), target R (9, row major), target t (3),
#          frame placement in the last joint (R 9, t 3), lower, upper, lower_active, upper_active,
#          rate_step (n each), joint placements in their parent joint (12 each), axes (3 each)
#: the loop's C source (native_servo.c, package data beside this module), read on first use
_SOURCE_FILE = "native_servo.c"

COMPILE_FLAGS = ("-O2", "-fPIC", "-shared")

_lock = threading.Lock()
_loaded: dict[str, object] = {}  # "lib" -> the ctypes function, or the reason it is missing
#: per chain, the C loop's arrays by (frame, active joints, options): Servo objects come and go per target
_by_chain: weakref.WeakKeyDictionary[KinematicChain, dict] = weakref.WeakKeyDictionary()


_compiler = c_compiler  # the one lookup (platkit.io.cache); a name here that tests may patch


def _library() -> Path | str:
    """The compiled servo in the cache directory (compiled there on the first call), or why not."""
    cc = _compiler()
    if cc is None:
        return "no C compiler (or PLATKIT_COMPILE=0)"
    source = c_source("platkit.chains", _SOURCE_FILE).replace("CHUNK_DONE_", str(CHUNK_DONE))
    return compiled_library(source, "servo", COMPILE_FLAGS, cc=cc, timeout=300)


def _chunk_function():
    """The compiled ``pk_servo_chunk`` (compiled and loaded on first use), or the reason it is missing."""
    with _lock:
        hit = _loaded.get("lib")
        if hit is not None:
            return hit
        built = _library()
        if isinstance(built, str):
            _loaded["lib"] = built
            return built
        try:
            fn = ctypes.CDLL(str(built)).pk_servo_chunk
        except OSError as exc:
            _loaded["lib"] = f"loading the compiled servo failed ({exc})"
            return _loaded["lib"]
        fn.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_int] * 3
        fn.restype = ctypes.c_int
        _loaded["lib"] = fn
        return fn


def compiled_servo_reason() -> str:
    """'' if the compiled loop is available, else why not (no compiler, PLATKIT_COMPILE=0, ...)."""
    fn = _chunk_function()
    return fn if isinstance(fn, str) else ""


def _kind(chain: KinematicChain, index: int) -> int:
    short = chain.model.joints[index].shortname()
    for axis, code in (("X", 0), ("Y", 1), ("Z", 2)):
        if short in (f"JointModelR{axis}", f"JointModelRUB{axis}"):
            return code
    if short.startswith("JointModelP"):
        return 4
    return 3


class CompiledServo:
    """The compiled one-target loop for one chain, link and target: :meth:`chunk` runs it.

    Built by :meth:`build` from what ``Servo._fast_case`` prepared (the chain, the link's frame
    id, the task's target (4, 4) and weights (6,), the options, the active joints (n,) bool);
    None where the compiled loop is not available or does not apply (more than
    :data:`MAX_JOINTS` joints)."""

    def __init__(self, fn, arrays: tuple, weights: np.ndarray, target: np.ndarray, n: int):
        self._fn = fn
        self.arrays = arrays  # (ints, doubles, their addresses): shared by the chain's servos, read only
        self.weights = weights
        self.target = target
        self.n = n

    @classmethod
    def build(cls, chain: KinematicChain, frame_id: int, target: np.ndarray, weights: np.ndarray, options,
              active: np.ndarray) -> CompiledServo | None:
        if chain.n > MAX_JOINTS:
            return None
        fn = _chunk_function()
        if isinstance(fn, str):
            return None
        d = options.damping
        key = (frame_id, active.tobytes(), options.gain, options.max_linear_step, options.max_angular_step, d.threshold,
               d.max_damping, d.error_scale, options.tol_position, options.tol_rotation, options.max_iterations,
               options.stall_iterations, options.use_rate_limits, options.dt)
        per_chain = _by_chain.get(chain)
        if per_chain is None:
            per_chain = _by_chain[chain] = {}
        hit = per_chain.get(key)
        if hit is None:
            if len(per_chain) > 64:  # options varied without end: keep the cache small
                per_chain.clear()
            ints, doubles = cls._arrays(chain, frame_id, options, active)
            hit = per_chain[key] = (ints, doubles, ints.ctypes.data, doubles.ctypes.data)
        return cls(fn, hit, np.asarray(weights, float), target, chain.n)

    @staticmethod
    def _arrays(chain: KinematicChain, frame_id: int, options, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ints, doubles) for the C loop, the weights and the target left at zero."""
        model = chain.model
        frame = model.frames[frame_id]
        joints = chain.supporting_joints(frame_id)
        d = options.damping
        ints = [chain.n, len(joints), options.max_iterations, options.stall_iterations, int(options.use_rate_limits),
                int(d.error_scale is not None)]
        ints += [int(a) for a in active] + [jt.column for jt in joints] + [_kind(chain, jt.index) for jt in joints]
        rate_step = np.where(np.isfinite(chain.rate), chain.rate * options.dt, np.inf)
        doubles = [options.gain, options.max_linear_step, options.max_angular_step, d.threshold, d.max_damping,
                   d.error_scale if d.error_scale is not None else 1.0, options.tol_position, options.tol_rotation]
        parts = [np.array(doubles), np.zeros(6), np.zeros(9), np.zeros(3),
                 frame.placement.rotation.ravel(), frame.placement.translation,
                 chain.lower, chain.upper, np.where(active, chain.lower, np.inf), np.where(active, chain.upper, -np.inf),
                 rate_step]
        parts += [np.concatenate([model.jointPlacements[jt.index].rotation.ravel(),
                                  model.jointPlacements[jt.index].translation]) for jt in joints]
        parts += [jt.axis for jt in joints]
        return np.ascontiguousarray(ints, dtype=np.intc), np.ascontiguousarray(np.concatenate(parts), dtype=float)

    def start(self, theta: np.ndarray) -> np.ndarray:
        """The work array of one attempt from theta (n,): the task's weights and target, theta
        (updated in place by the chunks),
        the state they carry (11: the iteration count, the best merit and its E (6), the stall
        reference and its iteration, the merit at the start), their outputs (12) and room for
        one chunk's path (CHUNK, n) and merits (CHUNK,)."""
        work = np.empty(18 + self.n * (CHUNK + 1) + 23 + CHUNK)
        work[:6] = self.weights
        work[6:15] = self.target[:3, :3].ravel()
        work[15:18] = self.target[:3, 3]
        work[18:18 + self.n] = theta
        return work

    def chunk(self, work: np.ndarray, first: bool, time_over: bool):
        """Up to :data:`CHUNK` iterations from the work array's theta (``first``: the state set
        from it; ``time_over``: the time cap is passed, checked before the first iteration).
        Returns (code, E (6,), merit, path (k, n), history (k,), norms): E and the merit at
        the theta reached, the k accepted steps of this chunk, and norms = (position error,
        rotation error, the best ones so far) over the weighted components (m, rad)."""
        n = self.n
        code = self._fn(self.arrays[2], self.arrays[3], work.ctypes.data, int(first), int(time_over), CHUNK)
        out = 18 + n + 11
        k = int(work[out + 7])
        path = out + 12
        history = path + CHUNK * n
        return (code, work[out:out + 6].copy(), float(work[out + 6]), work[path:path + k * n].reshape(k, n).copy(),
                work[history:history + k].copy(), work[out + 8:out + 12].tolist())


__all__ = ["CHUNK", "CONVERGED", "CHUNK_DONE", "CompiledServo", "ITERATION_CAP", "LINE_SEARCH_FAILED", "MAX_JOINTS",
           "STALLED", "TIME_CAP", "compiled_servo_reason"]
