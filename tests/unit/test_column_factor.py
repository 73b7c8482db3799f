"""The R factor identifiability chooses on: a tall matrix whose rows each move a part of the
columns (a tree's hands) is factored group by group, with the whole matrix's inner products."""
from __future__ import annotations

import numpy as np

from platkit.calibrate import factors
from platkit.calibrate.factors import column_factor


def _two_hands(rng: np.random.Generator) -> np.ndarray:
    """(600, 50): rows 0-299 move columns 0-29 (a trunk and the left arm), rows 300-599 columns
    0-9 and 30-49 (the trunk and the right arm)."""
    A = np.zeros((600, 50))
    A[:300, :30] = rng.normal(size=(300, 30))
    A[300:, :10] = rng.normal(size=(300, 10))
    A[300:, 30:] = rng.normal(size=(300, 20))
    return A


def test_rows_that_move_parts_of_the_columns_are_factored_by_part(monkeypatch):
    A = _two_hands(np.random.default_rng(3))
    shapes = []
    qr = np.linalg.qr

    def counted(B, mode="reduced"):
        shapes.append(B.shape)
        return qr(B, mode=mode)

    monkeypatch.setattr(factors.np.linalg, "qr", counted)
    R = column_factor(A)
    assert R.shape == (50, 50) and np.allclose(np.tril(R, -1), 0)
    np.testing.assert_allclose(R.T @ R, A.T @ A, rtol=0, atol=1e-12 * np.abs(A.T @ A).max())
    assert max(s[0] for s in shapes) < 600 and max(s[1] for s in shapes if s[0] == 300) < 50  # never all rows


def test_a_dense_matrix_is_one_qr():
    A = np.random.default_rng(4).normal(size=(200, 20))
    np.testing.assert_array_equal(column_factor(A), np.linalg.qr(A, mode="r"))


def test_columns_no_row_moves_keep_their_place():
    A = np.zeros((600, 52))
    A[:, :50] = _two_hands(np.random.default_rng(5))  # columns 50 and 51: the data do not depend on them
    R = column_factor(A)
    assert R.shape == (52, 52) and not R[:, 50:].any()
    np.testing.assert_allclose(R.T @ R, A.T @ A, rtol=0, atol=1e-12 * np.abs(A.T @ A).max())
