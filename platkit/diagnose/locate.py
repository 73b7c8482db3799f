"""Where calibrated residuals are structured: along time, along each control, in one marker.

Every residual component series (marker m, axis a: N numbers) is tested

- along time: Ljung-Box (autocorrelation) and a runs test (neighbours alike) in command order;
- along each control: a runs test with the poses sorted by that control (a smooth error in
  the control shows as long runs);
- per marker: a change point (a step in the marker's mean residual at one time), with a
  permutation p-value (the maximum over split points has no closed-form law).

All p-values are adjusted together (Holm by default, Benjamini-Hochberg on request): a
structure is *located* only if it survives testing the whole family. Residuals from a correct
model with white noise give no location in all but ``alpha`` of sessions.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from platkit.diagnose.stats import benjamini_hochberg, centred_rows, holm, ljung_box, neighbour_similarity, runs_test, runs_tests
from platkit.effects import history
from platkit.model import PlatformSpec
from platkit.poses import PoseSet

AXES = "xyz"


@dataclass
class Location:
    """One located structure: ``test`` (what was tested), ``where`` (marker, axis, control,
    time span, control region), the statistic, raw and adjusted p-values."""

    test: str
    where: dict[str, Any]
    statistic: float
    p: float
    p_adjusted: float = 1.0
    detail: dict[str, Any] = field(default_factory=dict)

    def sentence(self, unit: str = "mm") -> str:
        w = ", ".join(f"{k} {v}" for k, v in self.where.items())
        return f"{self.test} ({w}): statistic {self.statistic:.3g}, adjusted p = {self.p_adjusted:.2g}"


def _slip_statistic(x: np.ndarray) -> tuple[int, float]:
    """Best split k of x (n, d) and the between-segment sum of squares it explains."""
    n = len(x)
    x = x - x.mean(axis=0)
    c = np.cumsum(x, axis=0)
    j = np.arange(3, n - 2)
    if j.size == 0:
        return -1, 0.0
    e = np.sum(c[j - 1] ** 2, axis=1) * n / (j * (n - j))
    b = int(np.argmax(e))
    return int(j[b]), float(e[b] / max(np.sum(x**2), 1e-300))


def change_point_test(x: np.ndarray, n_perm: int = 199, rng: np.random.Generator | None = None) -> tuple[int, float, float]:
    """(k, fraction of variance the step explains, permutation p) for rows x (n, d) in time
    order; rows with NaN dropped (k then indexes the kept rows)."""
    x = x[np.all(np.isfinite(x), axis=1)]
    if len(x) < 8:
        return -1, 0.0, 1.0
    rng = rng or np.random.default_rng(0)
    k, s = _slip_statistic(x)
    exceed = sum(_slip_statistic(x[rng.permutation(len(x))])[1] >= s for _ in range(n_perm))
    return k, s, (1 + exceed) / (n_perm + 1)


def _region(values: np.ndarray, resid: np.ndarray, bins: int = 4, kept: dict | None = None) -> str:
    """The quarter of ``values`` where |mean residual| is largest, as 'lo..hi'. ``kept``: a dict
    for one ``values`` array, which keeps its quarters per set of finite residuals (the many
    residual columns of one session share them)."""
    ok = np.isfinite(values) & np.isfinite(resid)
    key = ok.tobytes()
    got = None if kept is None else kept.get(key)
    if got is None:
        v = values[ok]
        if v.size < bins:
            return "all"
        edges = np.quantile(v, np.linspace(0, 1, bins + 1))
        which = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, bins - 1)
        got = (edges, [(which == b) if np.any(which == b) else None for b in range(bins)])
        if kept is not None:
            kept[key] = got
    edges, members = got
    r = resid[ok]
    means = np.array([abs(np.mean(r[sel])) if sel is not None else 0.0 for sel in members])
    b = int(np.argmax(means))
    return f"{edges[b]:.6g}..{edges[b + 1]:.6g}"


def locate(residuals: np.ndarray, poses: PoseSet, spec: PlatformSpec, weights: np.ndarray | None = None,
           alpha: float = 0.01, method: str = "holm", n_perm: int = 199) -> list[Location]:
    """Test the residuals (N, M, 3) m of a fit of ``poses`` for structure; returns every test
    with its adjusted p-value, most significant first (``located(result, alpha)`` filters).

    ``weights`` (N, M): 0 marks observations the estimator rejected (treated as unseen).
    """
    r = np.array(residuals, float)
    if weights is not None:
        r[np.asarray(weights) <= 0] = np.nan
    N, M, _ = r.shape
    t = history(poses, "elapsed")
    order_t = np.argsort(t, kind="stable")
    tests: list[Location] = []
    names = poses.marker_names
    orders = np.array([np.argsort(poses.controls[:, i], kind="stable") for i in range(len(spec.controls))],
                      int).reshape(len(spec.controls), N)
    quarters: list[dict] = [{} for _ in spec.controls]
    for m in range(M):
        for a in range(3):
            x = r[:, m, a]
            if np.sum(np.isfinite(x)) < 8:
                continue
            base = {"marker": names[m], "axis": AXES[a]}
            Q, p = ljung_box(x[order_t])
            tests.append(Location("autocorrelation in time (Ljung-Box)", dict(base), Q, p,
                                  detail={"order": "time"}))
            z, p = runs_test(x[order_t])
            tests.append(Location("runs along time", dict(base), z, p, detail={"order": "time"}))
            zs, ps = runs_tests(x, orders)  # along every control at once
            for i, c in enumerate(spec.controls):
                z, p = float(zs[i]), float(ps[i])
                where = dict(base, control=c.name, region=_region(poses.controls[:, i], x, kept=quarters[i]) + f" {c.unit}")
                tests.append(Location(f"runs along {c.name}", where, z, p, detail={"order": c.name}))
    rng = np.random.default_rng(12345)
    for m in range(M):
        x = r[order_t, m, :]
        keep = np.all(np.isfinite(x), axis=1)
        k, s, p = change_point_test(x, n_perm=n_perm, rng=rng)
        if k > 0:
            times = t[order_t][keep]
            where = {"marker": names[m], "time_s": f"from {0.5 * (times[k - 1] + times[k]):.4g}"}
            tests.append(Location("step in the marker's residual (change point)", where, s, p))
    p = np.array([x.p for x in tests])
    adj = holm(p) if method == "holm" else benjamini_hochberg(p)
    for x, pa in zip(tests, adj):
        x.p_adjusted = float(pa)
    tests.sort(key=lambda x: (x.p_adjusted, x.p))
    return tests


def located(tests: list[Location], alpha: float = 0.01) -> list[Location]:
    """The tests that survive the family-wise correction at ``alpha``."""
    return [x for x in tests if x.p_adjusted < alpha]


def neighbour_pairs(poses: PoseSet, keep: np.ndarray | None = None, k: int = 3) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The neighbours :func:`neighbour_tests` compares, as index pairs (a, b) into ``poses`` among
    the ``keep`` poses: {"poses next in time": each pose and the next, "poses with near commands
    (k nearest)": each pose and its ``k`` nearest in the controls (scaled by their spread)}."""
    keep = np.ones(poses.n_poses, bool) if keep is None else np.asarray(keep, bool)
    idx = np.flatnonzero(keep)
    order = idx[np.argsort(history(poses, "elapsed")[idx], kind="stable")]
    U = np.asarray(poses.controls, float)[idx]
    spread = U.std(axis=0)
    U = (U - U.mean(axis=0)) / np.where(spread > 0, spread, 1.0)
    D = np.linalg.norm(U[:, None] - U[None], axis=2)
    np.fill_diagonal(D, np.inf)
    k = max(1, min(k, idx.size - 1))
    near = np.argsort(D, axis=1, kind="stable")[:, :k]
    return {"poses next in time": (order[:-1], order[1:]),
            f"poses with near commands ({k} nearest)": (np.repeat(idx, k), idx[near.reshape(-1)])}


def neighbour_tests(frames: dict[str, np.ndarray], poses: PoseSet, keep: np.ndarray | None = None, k: int = 3,
                    n_perm: int = 1999, seed: int = 12345) -> list[Location]:
    """Omnibus tests that a fit's residuals change smoothly, where the per-series tests of
    :func:`locate` each see a slice: are the residuals of poses next in time alike, and those of
    poses with near commands (:func:`neighbour_pairs`)? ``frames``: the residuals (N, M, 3) m in
    each frame to test them in, by the frame's name ("motion capture", "moving": a sway of
    the marker mount moves the markers along one direction of the moving part, which turns with
    the stand in the room's frame). Each pose's residual is the vector of all its markers'
    errors; the p-values are permutation p-values over the ``keep`` poses
    (stats.neighbour_similarity), adjusted together over every test and frame (Bonferroni); most
    significant first, each ``where`` {"alike": which neighbours, "frame": the frame}.

    A drift or sway shows along time; a plate that bends with the pose, or any error smooth over
    the workspace, shows over the commands. ``keep`` (N,) bool: the poses to test (those where the
    stand settled). Each test's ``detail`` holds its pairs (``a``, ``b``: indices into ``poses``).
    Fewer than 12 poses: no test."""
    keep = np.ones(poses.n_poses, bool) if keep is None else np.asarray(keep, bool)
    idx = np.flatnonzero(keep)
    if idx.size < 12:
        return []
    at = np.full(poses.n_poses, -1)
    at[idx] = np.arange(idx.size)  # a pose's row among the kept ones
    rng = np.random.default_rng(seed)
    pairs = neighbour_pairs(poses, keep, k)
    tests = []
    for frame, residuals in frames.items():
        R = np.asarray(residuals, float)[idx].reshape(idx.size, -1)
        for alike, (a, b) in pairs.items():
            s, p = neighbour_similarity(R, at[a], at[b], n_perm, rng)
            name = f"residuals alike at {alike.split(' (')[0]}" + (f", in the {frame} frame" if len(frames) > 1 else "")
            tests.append(Location(name, {"alike": alike, "frame": frame}, s, p, detail={"a": a, "b": b}))
    for x in tests:
        x.p_adjusted = min(1.0, x.p * len(tests))
    return sorted(tests, key=lambda x: x.p)


def along_main_direction(residuals: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What a neighbour test compares, for a plot: each pose's residual vector (all markers,
    taken from the poses' mean) at pairs (a, b), along the first principal direction of the
    paired poses' vectors; returns (at a, at b), m. Alike neighbours line up on the diagonal."""
    R = centred_rows(np.asarray(residuals, float).reshape(len(residuals), -1))
    direction = np.linalg.svd(R[np.unique(np.concatenate([a, b]))], full_matrices=False)[2][0]
    return R[a] @ direction, R[b] @ direction
