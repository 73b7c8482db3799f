"""The approach fits' normal equations compiled (platkit.settle): settle_fits.c beside this module
(package data), compiled once with the system C compiler into the cache folder
(:func:`platkit.native.compiled_library`, keyed by the hash of the source, the compiler and the
flags) and loaded through ctypes. Without a compiler, with ``PLATKIT_COMPILE=0``, or where the
compiler fails, the numpy path of platkit.settle._fits serves (:func:`fits_function` says why).

The compiled sums are the numpy path's up to rounding (another order of summation, the
exponentials of a block of samples from its first one's): the time constants searched and the
fitted approaches agree to rounding, not bit for bit.
"""
from __future__ import annotations

import ctypes
import threading
from collections.abc import Sequence

import numpy as np

from platkit.io.cache import c_compiler
from platkit.native import c_source, compiled_library

COMPILE_FLAGS = ("-O2", "-fPIC", "-shared")

_lock = threading.Lock()
_loaded: dict[str, object] = {}  # "fn" -> the ctypes function, or the reason it is missing

_compiler = c_compiler  # the one lookup (platkit.io.cache); a name here that tests may patch


def fits_function():
    """The compiled ``pk_settle_fits`` (compiled and loaded on first use), or why it is missing."""
    with _lock:
        hit = _loaded.get("fn")
        if hit is not None:
            return hit
        cc = _compiler()
        if cc is None:
            _loaded["fn"] = "no C compiler (or PLATKIT_COMPILE=0)"
            return _loaded["fn"]
        built = compiled_library(c_source("platkit.settle", "settle_fits.c"), "settle_fits", COMPILE_FLAGS, cc=cc,
                                 timeout=300)
        if isinstance(built, str):
            _loaded["fn"] = built
            return built
        try:
            fn = ctypes.CDLL(str(built)).pk_settle_fits
        except OSError as exc:
            _loaded["fn"] = f"loading the compiled approach fits failed ({exc})"
            return _loaded["fn"]
        fn.argtypes = [ctypes.c_int] * 3 + [ctypes.c_void_p] * 9 + [ctypes.c_int] + [ctypes.c_void_p] * 3
        fn.restype = ctypes.c_int
        _loaded["fn"] = fn
        return fn


def compiled_fits_reason() -> str:
    """'' if the compiled approach fits are available, else why not."""
    fn = fits_function()
    return fn if isinstance(fn, str) else ""


class Packed:
    """Holds (platkit.settle._fits._Hold) laid out for the compiled fits: their samples one after
    another (times s, centred markers y (K, Jp), 3 M columns padded with zeros to a multiple of
    16, weights w (K, M), every marker visible),
    ks the offsets of each hold's samples, seen and yty (H, M)."""

    def __init__(self, fn, holds: Sequence) -> None:
        self.fn = fn
        self.M = holds[0].w.shape[1]
        self.ks = np.concatenate([[0], np.cumsum([len(d.s) for d in holds])]).astype(np.int64)
        self.s = np.ascontiguousarray(np.concatenate([d.s for d in holds]), dtype=float)
        self.Jp = -(-3 * self.M // 16) * 16  # the columns padded to the kernel's 16
        self.y = np.zeros((int(self.ks[-1]), self.Jp))
        for d, k in zip(holds, self.ks):
            self.y[k:k + len(d.s), :3 * self.M] = d.y.reshape(len(d.s), -1)
        self.w = np.ascontiguousarray(np.concatenate([d.w for d in holds]), dtype=float)
        self.full = np.ascontiguousarray(self.w.min(axis=1) >= 1, dtype=np.uint8)
        self.seen = np.ascontiguousarray(np.stack([d.seen for d in holds]), dtype=np.uint8)
        self.yty = np.ascontiguousarray(np.stack([d.yty for d in holds]), dtype=float)

    def _call(self, taus: Sequence[np.ndarray], mode: int, *out: np.ndarray) -> np.ndarray:
        ts = np.concatenate([[0], np.cumsum([len(x) for x in taus])]).astype(np.int64)
        flat = np.ascontiguousarray(np.concatenate(taus), dtype=float)
        rss, G, B = out
        code = self.fn(len(self.ks) - 1, self.M, self.Jp, self.ks.ctypes.data, ts.ctypes.data, self.s.ctypes.data,
                       self.y.ctypes.data, self.w.ctypes.data, self.full.ctypes.data, self.seen.ctypes.data,
                       self.yty.ctypes.data, flat.ctypes.data, mode, rss.ctypes.data, G.ctypes.data, B.ctypes.data)
        if code != 0:
            raise MemoryError("the compiled approach fits ran out of memory")
        return ts

    def residuals(self, taus: Sequence[np.ndarray]) -> list[np.ndarray]:
        """(T_h,) the residual sum of squares over the seen markers of each hold at each of its
        time constants (as platkit.settle._fits._residuals)."""
        rss = np.empty(sum(len(x) for x in taus))
        empty = np.empty(1)
        ts = self._call(taus, 0, rss, empty, empty)
        return [rss[ts[h]:ts[h + 1]] for h in range(len(taus))]

    def equations(self, taus: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """(G, B) (H, M, 3, 3): each hold's normal equations at its time constant (regularised;
        the identity for a marker not seen) and their right-hand sides [param, coord]."""
        H = len(taus)
        G = np.empty((H, self.M, 3, 3))
        B = np.empty((H, self.M, 3, 3))
        self._call([np.array([float(x)]) for x in taus], 1, np.empty(1), G, B)
        return G, B
