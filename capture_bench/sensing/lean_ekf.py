"""filterpy's ``ExtendedKalmanFilter`` with ``predict`` and ``update`` written for speed: the filter
that `capture_bench.sensing.ekf.TargetEKF` runs (eq. 7 of the paper).

A module of its own so that importing the model (`capture_bench.sensing.ekf`) does not
import filterpy, whose import pulls in ``scipy.stats`` (a slow import, which a training process
that never builds a single-episode filter does without).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import lapack

FloatArray = NDArray[np.float64]


class LeanExtendedKalmanFilter(ExtendedKalmanFilter):
    """filterpy's ``ExtendedKalmanFilter`` with ``predict`` and ``update`` written for speed.

    The same equations, in the same form, leaving the same attributes (``x``, ``P``, ``K``, ``y``,
    ``S``, ``SI``, ``z``, ``x_prior``, ``P_prior``, ``x_post``, ``P_post``) as filterpy's methods:

    * predict: ``x = F x + B u``, ``P = F P F' + Q``;
    * update: ``S = H P H' + R``, ``K = P H' S^-1``, ``x = x + K (z - h(x))``, and the Joseph form
      ``P = (I - K H) P (I - K H)' + K R K'``.

    Two things differ, both only in how the numbers are computed: S^-1 comes from a Cholesky
    factorisation (LAPACK ``dpotrf``/``dpotrs``; S is symmetric positive definite) instead of
    ``scipy.linalg.inv``, and the per-call argument handling (``args``, scalar ``R``, ``residual``)
    is left out: ``update(z, HJacobian, Hx)`` with array ``z`` and the filter's own ``R`` (any other
    call goes to filterpy's method). On this 12-state, 8-measurement filter both are faster than
    filterpy's (``benchmarks/bench_estimator.py`` times the update against filterpy's: the table
    "The estimator's parts" of ``docs/speed.md``); the results agree with filterpy's to rounding
    (``tests/test_estimator.py``).

    Raises:
        numpy.linalg.LinAlgError: S is not positive definite (or not finite).
    """

    x: FloatArray
    P: FloatArray

    def __init__(self, dim_x: int, dim_z: int, dim_u: int = 0) -> None:
        super().__init__(dim_x, dim_z, dim_u)
        self._I_z = np.eye(dim_z)  # right-hand side that turns dpotrs into S^-1

    def predict(self, u: ArrayLike = 0) -> None:
        if not (np.isscalar(u) and u == 0):  # a control input: filterpy's own method
            super().predict(u)
            return
        F = self.F  # noqa: N806
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + self.Q
        self.x_prior = self.x.copy()
        self.P_prior = self.P.copy()

    def update(  # noqa: PLR0913 (filterpy's signature)
        self,
        z: ArrayLike | None,
        HJacobian: Callable[..., FloatArray],  # noqa: N803 (filterpy's names)
        Hx: Callable[..., FloatArray],  # noqa: N803
        R: object = None,  # noqa: N803
        args: tuple = (),
        hx_args: tuple = (),
        residual: Callable[..., FloatArray] = np.subtract,
    ) -> None:
        if z is None or R is not None or args or hx_args or residual is not np.subtract:
            super().update(z, HJacobian, Hx, R, args, hx_args, residual)
            return
        H = HJacobian(self.x)  # noqa: N806
        r: FloatArray = self.R
        PHT = self.P @ H.T  # noqa: N806
        self.S = S = H @ PHT + r  # noqa: N806
        chol, info = lapack.dpotrf(S)
        if info != 0 or not math.isfinite(S.sum()):
            raise np.linalg.LinAlgError(
                f"innovation covariance S is not positive definite (dpotrf info {info})"
            )
        self.SI, _ = lapack.dpotrs(chol, self._I_z)
        self.K = K = PHT @ self.SI  # noqa: N806
        self.y = np.subtract(z, Hx(self.x))
        self.x = self.x + K @ self.y
        I_KH = self._I - K @ H  # noqa: N806
        self.P = I_KH @ self.P @ I_KH.T + K @ r @ K.T
        self._log_likelihood = self._likelihood = self._mahalanobis = None
        self.z = np.array(z, dtype=float)
        self.x_post = self.x.copy()
        self.P_post = self.P.copy()
