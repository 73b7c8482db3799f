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

#: -ffp-contract=off: the kernels that give numpy's numbers bit for bit round each operation as numpy does
COMPILE_FLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off")

_lock = threading.Lock()
_loaded: dict[str, object] = {}  # "fn" -> the ctypes function, or the reason it is missing

_compiler = c_compiler  # the one lookup (platkit.io.cache); a name here that tests may patch


def fits_function():
    """The compiled kernels (:class:`Kernels`, compiled and loaded on first use), or why they are
    missing."""
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
            _loaded["fn"] = Kernels(ctypes.CDLL(str(built)))
        except (OSError, AttributeError) as exc:
            _loaded["fn"] = f"loading the compiled approach fits failed ({exc})"
        return _loaded["fn"]


def compiled_fits_reason() -> str:
    """'' if the compiled approach fits are available, else why not."""
    fn = fits_function()
    return fn if isinstance(fn, str) else ""


class Kernels:
    """The library's functions: ``pk_settle_prepare``, ``pk_settle_fits``, ``pk_settle_halves``,
    ``pk_settle_still``, ``pk_settle_trend``, ``pk_settle_mad``."""

    def __init__(self, lib: ctypes.CDLL) -> None:
        self.lib = lib
        self.prepare = lib.pk_settle_prepare
        self.prepare.argtypes = [ctypes.c_int] * 3 + [ctypes.c_void_p] * 11
        self.prepare.restype = ctypes.c_int
        self.fits = lib.pk_settle_fits
        self.fits.argtypes = [ctypes.c_int] * 3 + [ctypes.c_void_p] * 9 + [ctypes.c_int] + [ctypes.c_void_p] * 3
        self.fits.restype = ctypes.c_int
        self.halves = lib.pk_settle_halves
        self.halves.argtypes = [ctypes.c_longlong, ctypes.c_int, ctypes.c_int, ctypes.c_void_p, ctypes.c_longlong] + \
            [ctypes.c_void_p] * 4
        self.halves.restype = ctypes.c_int
        self.still = lib.pk_settle_still
        self.still.argtypes = [ctypes.c_longlong, ctypes.c_int, ctypes.c_int, ctypes.c_void_p, ctypes.c_longlong,
                               ctypes.c_double] + [ctypes.c_void_p] * 3
        self.still.restype = ctypes.c_int
        self.trend = lib.pk_settle_trend
        self.trend.argtypes = [ctypes.c_longlong, ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_longlong,
                               ctypes.c_double] + [ctypes.c_void_p] * 3
        self.trend.restype = ctypes.c_int
        self.mad = lib.pk_settle_mad
        self.mad.argtypes = [ctypes.c_longlong, ctypes.c_int, ctypes.c_void_p, ctypes.c_longlong] + [ctypes.c_void_p] * 2
        self.mad.restype = ctypes.c_int


def second_difference_mad(markers: np.ndarray) -> tuple[float, int] | None:
    """(median absolute deviation, count) of the finite second differences of a stream (K, M,
    3) by the compiled kernel, numpy's numbers (platkit.settle._still.estimate_noise; the MAD is
    NaN under 10 differences); None without the kernel."""
    kernels = fits_function()
    if isinstance(kernels, str):
        return None
    X, ld = _rows(markers)
    mad, count = ctypes.c_double(), ctypes.c_longlong()
    if kernels.mad(X.shape[0], 3 * X.shape[1], X.ctypes.data, ld, ctypes.addressof(mad),
                   ctypes.addressof(count)):
        raise MemoryError("the compiled noise estimate ran out of memory")
    return mad.value, count.value


def trend_statistic(t: np.ndarray, markers: np.ndarray, sigma2: float) -> tuple[float, int, float] | None:
    """(chi-square of the slopes, degrees of freedom, largest speed) of a window (t (K,), markers
    (K, M, 3)) by the compiled kernel, as platkit.settle._still.trend_test takes them (to
    rounding); None without the kernel."""
    kernels = fits_function()
    if isinstance(kernels, str):
        return None
    X, ld = _rows(markers)
    T = np.ascontiguousarray(t, dtype=float)
    stat, dof, vmax = ctypes.c_double(), ctypes.c_double(), ctypes.c_double()
    if kernels.trend(X.shape[0], X.shape[1], T.ctypes.data, X.ctypes.data, ld, float(sigma2), ctypes.addressof(stat),
                     ctypes.addressof(dof), ctypes.addressof(vmax)):
        raise MemoryError("the compiled trend test ran out of memory")
    return stat.value, int(dof.value), vmax.value


def still_statistics(markers: np.ndarray, n: int, sigma2: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """By the compiled kernel, numpy's numbers (platkit.settle._still.still_mask and
    approach_start) for a stretch (K, M, 3): (stat, the still test's statistic (K,); num, the
    sum of the squared differences of the halves over the markers seen in both (K,); m, how
    many those are (K,) int); None without the kernel."""
    kernels = fits_function()
    if isinstance(kernels, str):
        return None
    K, M = markers.shape[:2]
    X, ld = _rows(markers)
    stat, num, m = np.empty(K), np.empty(K), np.empty(K)
    if kernels.still(K, M, int(n), X.ctypes.data, ld, float(sigma2), stat.ctypes.data, num.ctypes.data, m.ctypes.data):
        raise MemoryError("the compiled still test ran out of memory")
    return stat, num, m.astype(np.intp)


def _rows(markers: np.ndarray) -> tuple[np.ndarray, int]:
    """A stream (K, M, 3) as the kernels read it: (array, ld), each row's 3 M values contiguous
    and rows ld doubles apart (a view of a wider table as it is; a copy otherwise)."""
    x = markers
    if not (x.dtype == np.float64 and x.ndim == 3 and x.shape[0] > 0 and x.strides[1:] == (24, 8)
            and x.strides[0] >= 24 * x.shape[1] and x.strides[0] % 8 == 0):
        x = np.ascontiguousarray(markers, dtype=float)
    return x, (x.strides[0] // 8 if x.shape[0] > 1 else 3 * x.shape[1])


def halves(markers: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """platkit.settle._still._halves of a stretch (K, M, 3) by the compiled kernel, bit for bit:
    (mb, ma (K, M, 3), nb, na (K, M)); None without the kernel."""
    kernels = fits_function()
    if isinstance(kernels, str):
        return None
    K, M = markers.shape[:2]
    X, ld = _rows(markers)
    mb, ma = np.empty((K, M, 3)), np.empty((K, M, 3))
    nb, na = np.empty((K, M)), np.empty((K, M))
    if kernels.halves(K, M, int(n), X.ctypes.data, ld, mb.ctypes.data, ma.ctypes.data, nb.ctypes.data, na.ctypes.data):
        raise MemoryError("the compiled still test ran out of memory")
    return mb, ma, nb, na


class Packed:
    """Stretches of one stream (the same M markers) prepared for the compiled fits by
    ``pk_settle_prepare``, as platkit.settle._fits._prepare and _prony_tau prepare one: their
    samples one after another, hold h at rows ks[h] = (first, end); per row the times s from
    the hold's first sample, the markers centred per marker over its visible samples y (N, Jp)
    (3 M columns padded with zeros to a multiple of 16, zero where occluded), the weights w
    (N, M) (1 visible, 0 occluded), full (every marker visible); per hold the visible samples
    nok, seen (nok >= 8), the markers' means (H, M, 3), yty (H, M) and Prony's time constant tp
    (H,) (NaN: none). :meth:`subset` shares the rows."""

    def __init__(self, kernels: Kernels, stretches: Sequence[tuple[np.ndarray, np.ndarray]]) -> None:
        self.kernels = kernels
        self.M = M = stretches[0][1].shape[1]
        ends = np.cumsum([len(t) for t, _ in stretches])
        self.ks = np.column_stack([ends - [len(t) for t, _ in stretches], ends]).astype(np.int64)
        N, H = int(ends[-1]), len(stretches)
        self.Jp = -(-3 * M // 16) * 16  # the columns padded to the kernel's 16
        t = np.ascontiguousarray(np.concatenate([t for t, _ in stretches]), dtype=float)
        X = np.ascontiguousarray(np.concatenate([x.reshape(len(x), 3 * M) for _, x in stretches]), dtype=float)
        self.s, self.y, self.w = np.empty(N), np.empty((N, self.Jp)), np.empty((N, M))
        self.full = np.empty(N, np.uint8)
        self.nok, self.mean, self.yty, self.tp = np.empty((H, M)), np.empty((H, M, 3)), np.empty((H, M)), np.empty(H)
        code = kernels.prepare(H, M, self.Jp, self.ks.ctypes.data, t.ctypes.data, X.ctypes.data, self.s.ctypes.data,
                               self.y.ctypes.data, self.w.ctypes.data, self.full.ctypes.data, self.nok.ctypes.data,
                               self.mean.ctypes.data, self.yty.ctypes.data, self.tp.ctypes.data)
        if code != 0:
            raise MemoryError("the compiled approach fits ran out of memory")
        self.seen = np.ascontiguousarray(self.nok >= 8, dtype=np.uint8)

    def subset(self, index: Sequence[int] | np.ndarray) -> Packed:
        """The holds ``index`` (their rows shared)."""
        out = object.__new__(Packed)
        out.__dict__.update(self.__dict__)
        index = np.asarray(index, dtype=np.intp)
        for name in ("ks", "nok", "mean", "yty", "tp", "seen"):
            setattr(out, name, np.ascontiguousarray(getattr(self, name)[index]))
        return out

    def _call(self, flat: np.ndarray, offsets: np.ndarray, mode: int, *out: np.ndarray) -> None:
        rss, G, B = out
        flat = np.ascontiguousarray(flat, dtype=float)
        offsets = np.ascontiguousarray(offsets, dtype=np.int64)
        code = self.kernels.fits(len(self.ks), self.M, self.Jp, self.ks.ctypes.data, offsets.ctypes.data,
                                 self.s.ctypes.data, self.y.ctypes.data, self.w.ctypes.data, self.full.ctypes.data,
                                 self.seen.ctypes.data, self.yty.ctypes.data, flat.ctypes.data, mode, rss.ctypes.data,
                                 G.ctypes.data, B.ctypes.data)
        if code != 0:
            raise MemoryError("the compiled approach fits ran out of memory")

    def residuals(self, flat: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """The residual sum of squares over the seen markers (as platkit.settle._fits._residuals)
        of hold h at its time constants flat[offsets[h]:offsets[h + 1]], in the same places."""
        rss = np.empty(len(flat))
        empty = np.empty(1)
        self._call(flat, offsets, 0, rss, empty, empty)
        return rss

    def equations(self, taus: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """(G, B) (H, M, 3, 3): each hold's normal equations at its time constant (regularised;
        the identity for a marker not seen) and their right-hand sides [param, coord]."""
        H = len(taus)
        G = np.empty((H, self.M, 3, 3))
        B = np.empty((H, self.M, 3, 3))
        self._call(np.asarray(taus, float), np.arange(H + 1), 1, np.empty(1), G, B)
        return G, B
