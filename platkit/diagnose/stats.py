"""Small statistics for residual diagnosis: multiple-testing corrections, runs and portmanteau
tests, the paired held-out test and the score (Lagrange multiplier) test of an added term.

All p-values are one-sided towards "structure" (fewer runs than chance, positive
autocorrelation, a better held-out prediction). A paired test over the windowed poses of a stream
is given their windows (:func:`serial_signed_rank`): neighbouring windows' errors are correlated.
"""
from __future__ import annotations

import numpy as np
from scipy import special, stats


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
    one-sided p-value of that. NaNs are dropped. :func:`runs_tests` in the one order given.
    """
    x = np.asarray(x, float)
    z, p = runs_tests(x, np.arange(x.size)[None])
    return float(z[0]), float(p[0])


def runs_tests(x: np.ndarray, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The runs test (:func:`runs_test`) of ``x`` (N,) in each order, the rows of ``orders`` (K, N)
    (permutations of range(N)): (z (K,), p (K,)), NaNs dropped from each order. The median and the
    counts above and below it do not depend on the order; only the runs are counted per order, all
    orders in one pass."""
    x = np.asarray(x, float)
    orders = np.asarray(orders, int)
    finite = np.isfinite(x)
    v = x[finite]
    s = x > np.median(v) if v.size else np.zeros(x.shape, bool)
    n1 = int(np.count_nonzero(s & finite))
    n2 = v.size - n1
    n = n1 + n2
    if n1 == 0 or n2 == 0 or n < 4:
        return np.zeros(len(orders)), np.ones(len(orders))
    seq = s[orders]
    if n < x.size:  # the finite entries of each order, in its order (each row keeps n of them)
        seq = seq[finite[orders]].reshape(len(orders), n)
    runs = 1 + np.count_nonzero(seq[:, 1:] != seq[:, :-1], axis=1)
    mu = 2.0 * n1 * n2 / n + 1
    var = 2.0 * n1 * n2 * (2.0 * n1 * n2 - n) / (n**2 * (n - 1))
    z = (runs - mu) / np.sqrt(max(var, 1e-300))
    return z, special.ndtr(z)


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
    return Q, float(special.chdtrc(h, Q))  # stats.chi2.sf's own function (Q >= 0 finite)


def paired_improvement(before: np.ndarray, after: np.ndarray, windows: np.ndarray | None = None) -> float:
    """One-sided p-value that ``after`` (per-pose held-out squared errors) is smaller than
    ``before`` (NaN pairs and equal pairs dropped; 1.0 with fewer than five left).

    ``windows`` None: independent poses (settled holds), the Wilcoxon signed-rank test on the
    paired differences. ``windows`` (N,) int: each pose's window of one stream, numbered in time
    order (windowed poses; fewer than five windows: 1.0): the errors of a window's poses and of
    neighbouring windows are correlated, and the signed-rank statistic's variance is taken with
    that correlation (:func:`serial_signed_rank`)."""
    before, after = np.asarray(before, float), np.asarray(after, float)
    ok = np.isfinite(before) & np.isfinite(after)
    d = before[ok] - after[ok]
    if windows is not None:
        w = np.asarray(windows, int)[ok]
        return serial_signed_rank(d[d != 0], w[d != 0])
    d = d[d != 0]
    if d.size < 5:
        return 1.0
    return float(stats.wilcoxon(d, alternative="greater").pvalue)


def bartlett_bandwidth(n_windows: int) -> int:
    """Lags (in windows) of the Bartlett kernel for ``n_windows`` windows: Newey and West's (1994)
    rule floor(4 (n / 100)^(2/9)): 2 for 5 to 27 windows, 3 for 28 to 100."""
    return int(np.floor(4.0 * (max(n_windows, 1) / 100.0) ** (2.0 / 9.0)))


def long_run_ratio(x: np.ndarray, windows: np.ndarray) -> float:
    """How many times the variance of sum(x) exceeds the independent one (the sum of the squares
    of x less its mean), for values ``x`` (N,) of windowed poses, ``windows`` (N,) int numbered in
    time order, at least 1.

    The long-run variance of the windows' sums of x less its mean: within a window every
    covariance counts (a window's nodes are one polynomial fit of the stream), between windows
    the lag-k autocovariances count with Bartlett weights 1 - k/(L+1) up to L =
    :func:`bartlett_bandwidth` (Newey-West). Over few windows that estimate is low by about
    (1 + 2 sum of the weights) / n_windows of itself (the mean taken out): it is divided by one
    minus that (at least 0.2). Floored at 1: a negative autocorrelation does not make a test bolder
    than one over independent poses."""
    x, windows = np.asarray(x, float), np.asarray(windows, int)
    ids, inv = np.unique(windows, return_inverse=True)
    n_w = ids.size
    c = x - x.mean()
    independent = float(c @ c)
    if n_w < 2 or independent <= 0:
        return 1.0
    S = np.bincount(inv, weights=c, minlength=n_w)
    L = min(bartlett_bandwidth(n_w), n_w - 1)
    weights = 1.0 - np.arange(1, L + 1) / (L + 1.0)
    long_run = float(S @ S) + 2.0 * sum(float(wk * (S[k:] @ S[:-k])) for k, wk in enumerate(weights, start=1))
    long_run /= max(1.0 - (1.0 + 2.0 * float(weights.sum())) / n_w, 0.2)
    return max(long_run / independent, 1.0)


def serial_signed_rank(d: np.ndarray, windows: np.ndarray) -> float:
    """One-sided p-value that the paired differences ``d`` (N,) of windowed poses lean positive,
    valid where the poses of a window and of neighbouring windows are correlated; ``windows`` (N,)
    int: each difference's window, numbered in time order. 1.0 with fewer than five windows.

    The statistic is Wilcoxon's, the sum of the signed ranks sign(d) rank(|d|), and under the null
    its signs are what is random: its variance is the independent one (the sum of the squared
    ranks) times the long-run variance ratio of the signs (:func:`long_run_ratio`: within windows
    and across neighbouring ones), and z = sum / sqrt(variance) is referred to Student's t with
    n_windows - 1 degrees of freedom (the ratio is estimated from that many windows).

    Why the signs' correlation and not the signed ranks': under an improvement the signed ranks
    are mostly ranks, and where the improvement varies smoothly along the stream their
    autocorrelation measures that variation, not the null's, and a held-out stream better at every
    pose would read as weakly as an even split. Why not Wilcoxon on block means: blocks long enough to
    decorrelate leave a held-out stream of 10 s (11 windows) too few means for any p under 0.01.
    Size measured on nulls with the held-out streams' own autocorrelation and on AR(1) nulls:
    docs/diagnosis-stream-tests.md.
    """
    d, windows = np.asarray(d, float), np.asarray(windows, int)
    n_w = np.unique(windows).size
    if n_w < 5:
        return 1.0
    s = np.sign(d) * stats.rankdata(np.abs(d))
    z = float(s.sum()) / np.sqrt(float(s @ s) * long_run_ratio(np.sign(d), windows))
    return float(stats.t.sf(z, n_w - 1))


def column_basis(J: np.ndarray) -> np.ndarray:
    """(n, rank) orthonormal basis of the column space of J (n, p)."""
    U, sv, _ = np.linalg.svd(J, full_matrices=False)
    return U[:, sv > sv[0] * 1e-10] if sv.size else U


def outside_basis(U: np.ndarray, J: np.ndarray) -> np.ndarray:
    """The part of the columns J (n, k) outside the span of the orthonormal U (n, p): J - U U^T J,
    by two matrix products over all of J's columns at once (U, often beyond the processor's cache,
    read twice however many columns; a column's numbers are those of its own products to
    rounding, the sums running in the matrix product's order)."""
    return J - U @ (U.T @ J)


def score_test(r: np.ndarray, J_base: np.ndarray, J_new: np.ndarray, dof: int,
               basis: np.ndarray | None = None, projected: np.ndarray | None = None) -> tuple[float, float, float]:
    """Lagrange-multiplier test that columns ``J_new`` (n, k) would reduce the residual ``r``
    (n,) of a least-squares fit with Jacobian ``J_base`` (n, p) (all weighted alike).
    ``basis``: column_basis(J_base), when many candidates are tested against one fit;
    ``projected``: J_new's part outside the basis (:func:`outside_basis`, computed for many
    candidates' columns at once), else computed here.

    Returns (F, p, separability): F = (|P r|^2 / k') / ((|r|^2 - |P r|^2) / (dof - k')) with P
    the projection on the part of J_new orthogonal to J_base and k' its rank; separability is the fraction of
    J_new's size outside J_base's column space (near 0: the term cannot be told apart from the
    geometry on this design).
    """
    if not J_new.any():  # every entry 0 (none NaN): no test, separability 0, as the products below give
        return 0.0, 1.0, 0.0
    if projected is None:
        projected = outside_basis(column_basis(J_base) if basis is None else basis, J_new)
    Jp = projected
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
    d = max(dof - k, 1)  # stats.f.sf's own function, without its checks, where F is a number >= 0
    return F, float(special.fdtrc(k, d, F) if np.isfinite(F) and F >= 0 else stats.f.sf(F, k, d)), sep


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
