"""The marker-offset columns written row block by row block (calibrate.term_columns.by_rows) give the
batched matrix product's numbers, and the pattern is refused where it would not."""
import numpy as np

from platkit.calibrate.term_columns import by_rows, one_row_columns


def _probe_like(n=40, markers=4, features=5, seed=3):
    rng = np.random.default_rng(seed)
    Y = np.zeros((n, 3 * markers, 3 * markers))  # each point's rows move with its own coordinates
    for i in range(markers):
        Y[:, 3 * i:3 * i + 3, 3 * i:3 * i + 3] = rng.normal(size=(n, 3, 3))
    d = np.zeros((n, 3 * markers, 3 * markers * features))
    for r in range(3 * markers):
        d[:, r, r * features:(r + 1) * features] = rng.normal(size=(n, features))
    return Y, d


def test_same_numbers_as_the_product_written_and_added():
    Y, d = _probe_like()
    Y[:, 4, 5] = 0.0  # a hole in one point's block: rows not contiguous for that column
    d[:, :, 7] = 0.0  # a column of zeros: its row's columns not contiguous
    pattern = one_row_columns(d)
    assert pattern is not None
    out = np.full((Y.shape[0], Y.shape[1], d.shape[2] + 3), 7.0)[:, :, 2:-1]  # a strided view, as in J
    assert by_rows(Y, d, pattern, out, first=True) is not None
    assert np.array_equal(out, np.matmul(Y, d))
    base = np.random.default_rng(4).normal(size=out.shape)
    out[...] = base
    assert by_rows(Y, d, pattern, out, first=False) is not None
    assert np.array_equal(out, base + np.matmul(Y, d))


def test_refused_where_a_column_moves_two_rows_or_the_jacobian_is_not_finite():
    Y, d = _probe_like()
    d2 = d.copy()
    d2[:, 1, 0] = 1.0  # column 0 now on rows 0 and 1: a sum of two products, the product's order matters
    assert one_row_columns(d2) is None
    assert one_row_columns(d[:, :, :6]) is None  # too few columns to gain anything
    pattern = one_row_columns(d)
    Y[3, 0, 7] = np.inf  # 0 * inf is NaN in the product: left to it
    out = np.zeros((Y.shape[0], Y.shape[1], d.shape[2]))
    assert by_rows(Y, d, pattern, out, first=True) is None
    assert not out.any()


def test_the_rows_each_column_was_written_in_hold_every_nonzero_of_the_product():
    Y, d = _probe_like()
    Y[:, 4, 5] = 0.0  # a hole: row 4 is not reached by column 5 of Y, nor by d's row 5's columns
    pattern = one_row_columns(d)
    out = np.empty((Y.shape[0], Y.shape[1], d.shape[2]))
    written = by_rows(Y, d, pattern, out, first=True)
    assert written is not None and written.shape == (Y.shape[1], d.shape[2])
    product = np.matmul(Y, d)
    assert not (product != 0).any(axis=0)[~written].any()  # zero at every pose outside them
    np.testing.assert_array_equal(written, (product != 0).any(axis=0))  # here exactly the nonzeros
    assert not written[4, 25:30].any() and written[3, 25:30].all()
