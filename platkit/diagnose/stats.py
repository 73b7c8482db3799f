"""Small statistics for residual diagnosis: multiple-testing corrections, runs and portmanteau
tests, the paired held-out test and the score (Lagrange multiplier) test of an added term.

All p-values are one-sided towards "structure" (fewer runs than chance, positive
autocorrelation, a better held-out prediction).
"""
from __future__ import annotations

import numpy as np
from scipy import stats


def holm(p: np.ndarray) -> np.ndarray:
    """Holm-Bonferroni adjusted p-values (same order as ``p``)."""
    p = np.asarray(p, float)
    n = p.size
    if n == 0:
        return p
    order = np.argsort(p)
    adj = np.minimum(1.0, np.maximum.accumulate((n - np.arange(n)) * p[order]))
    out = np.empty(n)
    out[order] = adj
    return out


def benjamini_hochberg(p: np.ndarray) -> np.ndarray:
    """Benjamini-Hochberg adjusted p-values (false discovery rate), same order as ``p``
    (scipy.stats.false_discovery_control)."""
    p = np.asarray(p, float)
    if p.size == 0:
        return p
    return stats.false_discovery_control(p, method="bh")


def runs_test(x: np.ndarray) -> tuple[float, float]:
    """Wald-Wolfowitz runs test of the signs of ``x`` about its median, in the given order.

    Returns (z, p): z < 0 means fewer runs than chance (neighbours alike: structure); p is the
    one-sided p-value of that. NaNs are dropped.
    """
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    s = x > np.median(x)
    n1, n2 = int(s.sum()), int((~s).sum())
    n = n1 + n2
    if n1 == 0 or n2 == 0 or n < 4:
        return 0.0, 1.0
    runs = 1 + int(np.sum(s[1:] != s[:-1]))
    mu = 2.0 * n1 * n2 / n + 1
    var = 2.0 * n1 * n2 * (2.0 * n1 * n2 - n) / (n**2 * (n - 1))
    z = (runs - mu) / np.sqrt(max(var, 1e-300))
    return float(z), float(stats.norm.cdf(z))


def ljung_box(x: np.ndarray, lags: int | None = None) -> tuple[float, float]:
    """Ljung-Box portmanteau test of whiteness of ``x`` in the given order: (Q, p)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    n = x.size
    if n < 8:
        return 0.0, 1.0
    h = lags or max(1, min(10, n // 5))
    x = x - x.mean()
    c0 = float(x @ x) / n
    if c0 <= 0:
        return 0.0, 1.0
    rho = np.array([float(x[k:] @ x[:-k]) / n / c0 for k in range(1, h + 1)])
    Q = n * (n + 2) * float(np.sum(rho**2 / (n - np.arange(1, h + 1))))
    return Q, float(stats.chi2.sf(Q, h))


def paired_improvement(before: np.ndarray, after: np.ndarray) -> float:
    """One-sided p-value that ``after`` (per-pose held-out squared errors) is smaller than
    ``before``: Wilcoxon signed-rank on the paired differences (NaN pairs dropped)."""
    before, after = np.asarray(before, float), np.asarray(after, float)
    ok = np.isfinite(before) & np.isfinite(after)
    d = before[ok] - after[ok]
    d = d[d != 0]
    if d.size < 5:
        return 1.0
    return float(stats.wilcoxon(d, alternative="greater").pvalue)


def column_basis(J: np.ndarray) -> np.ndarray:
    """(n, rank) orthonormal basis of the column space of J (n, p)."""
    U, sv, _ = np.linalg.svd(J, full_matrices=False)
    return U[:, sv > sv[0] * 1e-10] if sv.size else U


def score_test(r: np.ndarray, J_base: np.ndarray, J_new: np.ndarray, dof: int,
               basis: np.ndarray | None = None) -> tuple[float, float, float]:
    """Lagrange-multiplier test that columns ``J_new`` (n, k) would reduce the residual ``r``
    (n,) of a least-squares fit with Jacobian ``J_base`` (n, p) (all weighted alike).
    ``basis``: column_basis(J_base), when many candidates are tested against one fit.

    Returns (F, p, separability): F = (|P r|^2 / k') / ((|r|^2 - |P r|^2) / (dof - k')) with P
    the projection on the part of J_new orthogonal to J_base and k' its rank; separability is the fraction of
    J_new's size outside J_base's column space (near 0: the term cannot be told apart from the
    geometry on this design).
    """
    U = column_basis(J_base) if basis is None else basis
    Jp = J_new - U @ (U.T @ J_new)
    size = np.linalg.norm(J_new, axis=0)
    sep = float(np.min(np.linalg.norm(Jp, axis=0) / np.maximum(size, 1e-300))) if J_new.size else 0.0
    if sep < 1e-6:  # inside J_base's span, or no columns at all (a term no marker moves with): no test
        return 0.0, 1.0, sep
    Q, s2, _ = np.linalg.svd(Jp, full_matrices=False)
    keep = s2 > (s2[0] if s2.size else 0) * 1e-8
    if not keep.any():
        return 0.0, 1.0, sep
    Q = Q[:, keep]
    k = Q.shape[1]
    explained = float(np.sum((Q.T @ r) ** 2))
    F = (explained / k) / max((float(r @ r) - explained) / max(dof - k, 1), 1e-300)
    return F, float(stats.f.sf(F, k, max(dof - k, 1))), sep


def bic(rss: float, n_obs: int, n_params: int) -> float:
    """Bayesian information criterion of a Gaussian least-squares fit."""
    return n_obs * np.log(max(rss, 1e-300) / n_obs) + n_params * np.log(n_obs)


def centred_rows(R: np.ndarray) -> np.ndarray:
    """The rows of ``R`` (N, D) taken from their mean over the finite entries of each column;
    NaN entries become 0."""
    R = np.asarray(R, float)
    seen = np.isfinite(R)
    return np.where(seen, R - np.nansum(R, axis=0) / np.maximum(seen.sum(axis=0), 1), 0.0)


def neighbour_similarity(R: np.ndarray, a: np.ndarray, b: np.ndarray, n_perm: int = 1999,
                         rng: np.random.Generator | None = None) -> tuple[float, float]:
    """Are the rows of ``R`` (N, D) alike at the index pairs (a[k], b[k])? A permutation test.

    The statistic is the mean inner product of the paired rows over the mean squared row, each
    row taken from the rows' mean (:func:`centred_rows`; a correlation: near 0 for rows that are
    independent, up to 1 when paired rows are equal); its null is the same statistic with the
    rows' labels shuffled (``n_perm`` times). Returns
    (statistic, one-sided p that paired rows are more alike than chance). NaN entries count as 0.

    A least-squares fit's residuals are not exchangeable (r = (I - H) e), but where the pairs are
    poses whose Jacobian rows are alike the projection makes them less alike, not more: the test
    is conservative there (clean physical sessions: none of 225 under 0.01 over poses with near
    commands, 3 of 225 over poses next in time).
    """
    R = centred_rows(R)
    a, b = np.asarray(a, int), np.asarray(b, int)
    den = float(np.mean(np.sum(R * R, axis=1)))
    if a.size == 0 or den <= 0:
        return 0.0, 1.0
    s0 = float(np.mean(np.sum(R[a] * R[b], axis=1))) / den
    rng = rng or np.random.default_rng(0)
    exceed = 0
    for start in range(0, n_perm, 250):  # shuffles of the row labels, 250 at a time
        P = np.argsort(rng.random((min(250, n_perm - start), len(R))), axis=1)
        s = np.einsum("pkd,pkd->p", R[P[:, a]], R[P[:, b]]) / a.size / den
        exceed += int(np.sum(s >= s0))
    return s0, float((1 + exceed) / (n_perm + 1))
