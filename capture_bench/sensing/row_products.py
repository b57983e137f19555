"""Matrix products whose rows do not depend on the other rows of the call.

A batched filter or solver treats each row of its arrays as one episode's, and an episode must
play the same whichever episodes share its call (a batch of 4 validation seeds or of 64
training episodes; a sub-env's EKF beside 15 others or beside 63). numpy's ``A @ B`` on 2-D
arrays is one BLAS ``dgemm``, and OpenBLAS computes the last row of an odd number of rows with
another kernel than the rest (measured here with K = 12 and 31 columns: with M odd, row M - 1
differs in its last bits from the same row in any even-height product; with K = 4 it does not).
:func:`row_stable_matmul` always hands BLAS an even number of rows, so that every row comes out
as it does in any even-height product.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def row_stable_matmul(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a @ b`` for a (M, K) and b (K, N), each row as in any product with an even number of
    rows (an odd M gets its last row twice, and drops the copy): (M, N)."""
    m = a.shape[0]
    if m % 2 == 0:
        return a @ b
    return (np.concatenate((a, a[-1:]), axis=0) @ b)[:m]
