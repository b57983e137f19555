"""Row-stable matrix products (`capture_bench.sensing.row_products`), which photogrammetry's
batched solves use so that an image's solution does not depend on the other images of the call."""

from __future__ import annotations

import numpy as np

from capture_bench.sensing.row_products import row_stable_matmul


def test_row_stable_products_give_each_row_as_an_even_height_product_does():
    """With 12 or 31 columns, OpenBLAS rounds the last row of an odd-height product its own way;
    row_stable_matmul's rows equal those of the even-height product of the same rows and more."""
    rng = np.random.default_rng(2)
    for k in (4, 12, 31):
        a, b = rng.normal(size=(65, k)), rng.normal(size=(k, 56))
        even = a @ b  # 65 rows: row 64 is the odd one out, rows 0..63 the reference
        for m in (1, 2, 3, 17, 64):
            np.testing.assert_array_equal(row_stable_matmul(a[:m], b), even[:m])
        np.testing.assert_array_equal(row_stable_matmul(a, b)[:64], even[:64])
    # Past ~262,144 multiply-adds OpenBLAS shares the rows between threads, each share's odd
    # last row rounded its own way: in chunks, every row is still as it is alone.
    a, b = rng.normal(size=(1537, 31)), rng.normal(size=(31, 84))
    alone = np.concatenate([row_stable_matmul(row[None], b) for row in a])
    for m in (513, 514, 1026, 1537):
        np.testing.assert_array_equal(row_stable_matmul(a[:m], b), alone[:m])
