"""Matrix products whose rows do not depend on the other rows of the call.

A batched filter or solver treats each row of its arrays as one episode's, and an episode must
play the same whichever episodes share its call (a batch of 4 validation seeds or of 64
training episodes; a sub-env's EKF beside 15 others or beside 63). numpy's ``A @ B`` on 2-D
arrays is one BLAS ``dgemm``, and OpenBLAS rounds some rows by where they fall, not by what they
hold:

* it computes the last row of an odd number of rows with another kernel (measured here with
  K = 12 and 31 columns: with M odd, row M - 1 differs in its last bits from the same row in any
  even-height product; with K = 4 it does not);
* above M * K * N = 262,144 multiply-adds it splits the rows between threads, and the last row
  of an odd-height share takes that kernel again (with 2 threads, M = 513: rows 128 and 385).

`row_stable_matmul` hands BLAS chunks of an even number of rows, each small enough to run
on one thread, so every row comes out as it does in a small even-height product.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Multiply-adds per product below which OpenBLAS stays on one thread (its
#: ``GEMM_MULTITHREAD_THRESHOLD`` of 4 x 65,536), halved for margin.
SINGLE_THREAD_WORK = 131_072


def row_stable_matmul(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a @ b`` for a (M, K) and b (K, N), each row as in a small product with an even number
    of rows: chunks of an even height of at most `SINGLE_THREAD_WORK` / (K N) rows (at
    least 2), an odd last chunk getting its last row twice (the copy dropped): (M, N)."""
    m, k = a.shape
    rows = max(2, SINGLE_THREAD_WORK // max(1, k * b.shape[1]) // 2 * 2)
    if m <= rows:
        return _even_product(a, b)
    out = np.empty((m, b.shape[1]), dtype=np.result_type(a, b))
    for start in range(0, m, rows):
        out[start : start + rows] = _even_product(a[start : start + rows], b)
    return out


def _even_product(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a @ b`` through an even number of rows (an odd M: the last row twice, then dropped)."""
    m = a.shape[0]
    if m % 2 == 0:
        return a @ b
    return (np.concatenate((a, a[-1:]), axis=0) @ b)[:m]
