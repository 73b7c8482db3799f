"""Which parameters a data set can fix: pivoted orthogonalisation of the scaled identification Jacobian.

The identification Jacobian ``J`` (n_obs, n_par) maps small parameter changes to marker
displacements. Each column is scaled by its parameter's typical size (1 mm, 1 mrad, ...) so that
columns compare. Parameters are taken in priority tiers (the base-to-mocap transform and the
marker positions first: without them nothing is predicted; then model terms; then the stand's
td). Within a tier, the column with the largest component outside the span of the columns
already chosen is taken next (QR with column pivoting, as FIGAROH chooses base parameters); a
column whose remaining component is below ``rel_tol`` of its own norm is *held at nominal* and
reported with the combination of chosen parameters it is aliased with. Nothing is absorbed
silently.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: a column keeping less than this fraction of its norm outside the chosen span is not identifiable
DEFAULT_REL_TOL = 1e-6


@dataclass
class HeldParameter:
    """A parameter the data cannot fix, held at its nominal value.

    ``combination``: the direction the data cannot see, as {parameter name: coefficient} in
    scaled units (this parameter 1.0, then the chosen ones it trades against, largest first).
    """

    name: str
    reason: str
    combination: dict[str, float] = field(default_factory=dict)
    remaining: float = 0.0  # fraction of the column's norm outside the chosen span

    def to_dict(self) -> dict:
        return {"name": self.name, "reason": self.reason, "remaining_fraction": float(self.remaining),
                "combination": {k: float(v) for k, v in self.combination.items()}}


@dataclass
class Identifiability:
    """Result of :func:`select_identifiable`."""

    chosen: list[int]  # column indices estimated, in the order chosen
    held: list[HeldParameter]
    singular_values: np.ndarray  # of the scaled Jacobian of all candidate columns, descending
    condition_number: float  # of the chosen columns (scaled)
    names: list[str]

    def to_dict(self) -> dict:
        return {
            "n_candidates": len(self.names),
            "n_identifiable": len(self.chosen),
            "held_at_nominal": [h.to_dict() for h in self.held],
            "singular_values": [float(s) for s in self.singular_values],
            "condition_number": float(self.condition_number),
        }


def select_identifiable(J: np.ndarray, names: list[str], scale: np.ndarray, tiers: list[int],
                        rel_tol: float = DEFAULT_REL_TOL, max_terms: int = 6) -> Identifiability:
    """Choose the columns of ``J`` the data fixes.

    J: (n_obs, n) identification Jacobian in SI; names: n parameter names; scale: (n,) typical
    size of each parameter (SI); tiers: (n,) priority, lower first. Returns an
    :class:`Identifiability` whose ``chosen`` columns are linearly independent to ``rel_tol``.
    """
    J = np.asarray(J, float)
    scale = np.asarray(scale, float)
    Js = J * scale[None, :]
    n = Js.shape[1]
    norms = np.linalg.norm(Js, axis=0)
    basis: list[np.ndarray] = []  # orthonormal vectors spanning the chosen columns
    chosen: list[int] = []
    held: list[HeldParameter] = []
    tiers = np.asarray(tiers)
    for tier in sorted(set(tiers.tolist())):
        pending = [j for j in range(n) if tiers[j] == tier]
        rest = {j: Js[:, j].copy() for j in pending}
        # re-orthogonalise remaining columns against the basis built so far
        for j in pending:
            for b in basis:
                rest[j] -= b * (b @ rest[j])
        while pending:
            frac = {j: (np.linalg.norm(rest[j]) / norms[j] if norms[j] > 0 else 0.0) for j in pending}
            best = max(pending, key=lambda j: (np.linalg.norm(rest[j]), -j))
            if frac[best] < rel_tol or norms[best] == 0:
                break
            v = rest[best]
            # twice for numerical orthogonality
            for b in basis:
                v = v - b * (b @ v)
            v = v / np.linalg.norm(v)
            basis.append(v)
            chosen.append(best)
            pending.remove(best)
            for j in pending:
                rest[j] = rest[j] - v * (v @ rest[j])
        if pending and chosen:
            C = Js[:, chosen]
            coefs = np.linalg.solve(C.T @ C, C.T @ Js[:, pending])  # (n_chosen, n_pending)
        for jj, j in enumerate(pending):
            remaining = float(np.linalg.norm(rest[j]) / norms[j]) if norms[j] > 0 else 0.0
            if norms[j] == 0:
                reason = "the data do not depend on it at all"
                combo = {names[j]: 1.0}
            else:
                reason = "its effect on the markers is a combination of parameters estimated before it"
                coef = coefs[:, jj]
                order = np.argsort(-np.abs(coef))
                combo = {names[j]: 1.0}
                for k in order[:max_terms]:
                    if abs(coef[k]) >= 0.05 * max(1e-300, np.max(np.abs(coef))):
                        combo[names[chosen[k]]] = -float(coef[k])
            held.append(HeldParameter(names[j], reason, combo, remaining))
    sv = singular_values(Js) if n else np.zeros(0)
    if chosen:
        s_chosen = singular_values(Js[:, chosen])
        cond = float(s_chosen[0] / s_chosen[-1]) if s_chosen[-1] > 0 else float("inf")
    else:
        cond = float("nan")
    return Identifiability(chosen, held, sv, cond, list(names))


def singular_values(A: np.ndarray) -> np.ndarray:
    """Singular values (descending) of a matrix: of its R factor (QR first, which is cheap for the
    tall identification Jacobians), to full relative accuracy."""
    A = np.asarray(A, float)
    if A.shape[0] > 2 * A.shape[1]:
        A = np.linalg.qr(A, mode="r")
    return np.linalg.svd(A, compute_uv=False)


def null_space_combinations(J: np.ndarray, names: list[str], scale: np.ndarray, rel_tol: float = 1e-8,
                            max_terms: int = 8) -> list[dict[str, float]]:
    """The parameter combinations with (numerically) zero effect, by name, from the SVD.

    Returns one {name: coefficient} per null direction (scaled units, largest |coefficient|
    first, those under 5% of the largest left out).
    """
    Js = np.asarray(J, float) * np.asarray(scale, float)[None, :]
    _, s, Vt = np.linalg.svd(Js, full_matrices=True)
    s_full = np.zeros(Vt.shape[0])
    s_full[: len(s)] = s
    out = []
    top = s[0] if len(s) else 0.0
    for k in np.nonzero(s_full <= rel_tol * top)[0]:
        v = Vt[k]
        order = np.argsort(-np.abs(v))
        combo = {}
        for j in order[:max_terms]:
            if abs(v[j]) >= 0.05 * np.max(np.abs(v)):
                combo[names[j]] = float(v[j])
        out.append(combo)
    return out
