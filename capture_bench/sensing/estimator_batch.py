"""n independent ``TargetEstimator(source="ekf")`` stepped together with stacked numpy arrays.

The batched twin of `capture_bench.sensing.estimator.TargetEstimator` with the ``"ekf"``
source, for a vectorised environment: env i of `BatchedTargetEstimator.update` gets exactly
what env i would get from its own estimator fed the same frames and periods (tests check it step by
step, to rounding): the same initialisation from an accepted cold photogrammetry solve, predict(dt)
then update, predict-only without a frame, divergence rules, re-initialisation, Euler-angle
wrapping, global-frame output (eqs. 11-12) and status. The rules and constants come from
`capture_bench.sensing.estimator` and `capture_bench.sensing.ekf`; see their docstrings.

Why two filters: each is the faster where it runs. Per episode and update, this one's cost falls
as n grows (each numpy call's overhead is shared by the batch), and with tens of episodes
(recordings, ``CaptureVectorEnv``) it is far below the single filter's; at n = 1 that overhead is
all of it, and the single filter (one episode's, the single env's) is the faster
(``OPENBLAS_NUM_THREADS=1 taskset -c 0 python benchmarks/bench_estimator_batch.py --clock cpu``
times both; the table "The batched estimator" of ``docs/speed.md`` holds its figures).

The filter (eqs. 3-7) is the single filter's, with its state permuted into blocks,
``X = (q, q_dot)`` with ``q = (x, y, z, theta_x, theta_y, theta_z)`` the pose (the paper orders
the same 12 numbers ``(x, x_dot, y, y_dot, ...)``; `BatchedTargetEstimator.state` gives that
order). In blocks the model's structure is plain:

* eq. 4: ``A = I + t_s [[0, I], [0, 0]]`` (a shift of the rates into the pose), so ``A P A'`` is
  two in-place row/column operations;
* eq. 5: ``B Q B' = [[t_s^4/4, t_s^3/2], [t_s^3/2, t_s^2]] (x) diag(sigma_a^2 I_3,
  sigma_alpha^2 I_3)``;
* eq. 6: ``H = [J, 0]`` with J (8, 6) the analytic Jacobian of the image points in the pose
  (`capture_bench.sensing.photogrammetry.project_poses`), so ``P H' = P[:, :6] J'``;
* eq. 7: ``S = H P H' + R`` (Cholesky ``S = L L'``: the positive-definiteness test of the single
  filter), ``K = P H' S^-1`` with ``S^-1 = L^-T L^-1``, ``X += K (z - h(X))``, the NIS
  ``|L^-1 (z - h)|^2``, and the Joseph form ``P = (I - K H) P (I - K H)' + K R K'``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.ekf import (
    POSE_INDEX,
    default_initial_covariance,
    measurement_sigma,
    wrap_angle,
)
from capture_bench.sensing.estimator import (
    DIVERGENCE_FRAMES,
    NIS_LIMIT,
    NOISE_FLOOR_PX,
    PARTIAL_FRAME_RULES,
    STATUSES,
    acceptance_residual,
    solution_accepted,
    state_to_global,
)
from capture_bench.sensing.photogrammetry import project_poses, projection_table, solve_pose_batch
from capture_bench.sensing.row_products import row_stable_matmul

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

OK, PREDICTING, INITIALISING, DIVERGED = (
    STATUSES.index(s) for s in ("ok", "predicting", "initialising", "diverged")
)
_VALID = np.array([s in ("ok", "predicting") for s in STATUSES])  # status -> estimate valid

# Block state (q, q_dot) -> paper order: X_paper[BLOCK_ORDER] = X_block.
BLOCK_ORDER = np.concatenate([POSE_INDEX, POSE_INDEX + 1])
PAPER_ORDER = np.argsort(BLOCK_ORDER)  # X_block[PAPER_ORDER] = X_paper
_ANGLES = slice(3, 6)  # theta_x, theta_y, theta_z in the block state


@dataclass
class BatchedEstimates:
    """One step of n estimators, global frame (the fields of n `TargetEstimate`).

    Attributes:
        position: capture point, m, (n, 3); NaN where not valid.
        velocity: capture point velocity, m/s, (n, 3); NaN where not valid.
        covariance: (n, 6, 6) covariance of (position, velocity); NaN where not valid (where
            ``TargetEstimate.covariance`` is None).
        valid: (n,) whether position and velocity hold an estimate.
        status: (n,) int8 index into `capture_bench.sensing.estimator.STATUSES`.

    Rows of envs that were not active in the step carry no estimate (NaN, not valid) and their
    previous status.
    """

    position: FloatArray
    velocity: FloatArray
    covariance: FloatArray
    valid: BoolArray
    status: NDArray[np.int8]

    def status_names(self) -> list[str]:
        """The statuses as the strings of `TargetEstimate`."""
        return [STATUSES[s] for s in self.status]


@dataclass
class FilterRows:
    """The complete state of m rows of a `BatchedTargetEstimator`: what their next
    `update` reads, so that another estimator given it
    (`restore`) continues those filters bit for bit.

    Attributes:
        x: (m, 12) states, block order, camera frame; P: (m, 12, 12) their covariances.
        initialised, diverged: (m,) flags; high_nis, reinitialisations: (m,) counters;
        status: (m,) int8 index into `capture_bench.sensing.estimator.STATUSES`.
    """

    x: FloatArray
    P: FloatArray
    initialised: BoolArray
    diverged: BoolArray
    high_nis: NDArray[np.int64]
    reinitialisations: NDArray[np.int64]
    status: NDArray[np.int8]

    @classmethod
    def stack(cls, parts: list[FilterRows]) -> FilterRows:
        """The rows of ``parts``, in order, as one `FilterRows`."""
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)))


def _rows(mask: BoolArray) -> slice | NDArray[np.intp]:
    """Index of the True rows: a slice (a view, no copy) when all are."""
    return slice(None) if mask.all() else np.flatnonzero(mask)


def _lower_inverse(lower: FloatArray) -> FloatArray:
    """L^-1 of lower-triangular matrices (m, k, k), by forward substitution.

    With D = diag(L) and the unit lower-triangular U = D^-1 L, row i of U^-1 is
    ``e_i - U[i, :i] U^-1[:i]``; then L^-1 = U^-1 D^-1.
    """
    k = lower.shape[-1]
    diag = lower[:, np.arange(k), np.arange(k)]
    unit = lower / diag[:, :, None]
    inv = np.zeros_like(lower)
    inv[:, 0, 0] = 1.0
    for i in range(1, k):
        np.negative((unit[:, i : i + 1, :i] @ inv[:, :i, :i])[:, 0], out=inv[:, i, :i])
        inv[:, i, i] = 1.0
    return inv / diag[:, None, :]


def _cholesky(s: FloatArray) -> tuple[FloatArray, BoolArray]:
    """Cholesky factors L (m, k, k) of S, and which S were finite and positive definite.

    The rows that were not have L = I (unused). The rule of the single filter (LAPACK's
    ``dpotrf`` fails, or the sum of S is not finite).
    """
    ok = np.isfinite(s.sum(axis=(1, 2)))
    eye = np.eye(s.shape[-1])
    if not ok.all():
        s = np.where(ok[:, None, None], s, eye)
    try:
        return np.linalg.cholesky(s).astype(float, copy=False), ok
    except np.linalg.LinAlgError:  # rare: factor one by one and mark the failures
        lower = np.empty_like(s)
        for i in range(s.shape[0]):
            try:
                lower[i] = np.linalg.cholesky(s[i])
            except np.linalg.LinAlgError:
                lower[i], ok[i] = eye, False
        return lower, ok


class BatchedTargetEstimator:
    """n independent ``TargetEstimator(source="ekf")``, stepped together.

    Args:
        n: number of estimators (envs).
        camera_model: the (fixed) camera's geometry, shared by all envs.
        feature_points: feature points in the target frame, metres, shape (N, 3).
        noise_px: image noise the estimators assume, pixels (sets R and acceptance).
        sigma_acceleration: process noise sigma_a, m/s^2.
        sigma_angular_acceleration: process noise sigma_alpha, rad/s^2.

    Attributes:
        x: (n, 12) states in block order ``(q, q_dot)`` (see the module docstring), camera frame.
        P: (n, 12, 12) their covariances, block order. ``update`` may replace both arrays
            (read them after the call rather than keeping references).
        initialised, diverged: (n,) bool flags of each env's filter.
        high_nis: (n,) consecutive updates with NIS > ``NIS_LIMIT``.
        reinitialisations: (n,) times each filter restarted after a divergence.
    """

    def __init__(
        self,
        n: int,
        camera_model: CameraModel,
        feature_points: ArrayLike,
        noise_px: float = 1.0,
        sigma_acceleration: float = 0.01,
        sigma_angular_acceleration: float = 0.01,
        partial_frames: str = "update",
    ) -> None:
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        if partial_frames not in PARTIAL_FRAME_RULES:
            raise ValueError(
                f"unknown partial_frames {partial_frames!r}; valid: {PARTIAL_FRAME_RULES}"
            )
        self.partial_frames = partial_frames
        self.n = int(n)
        self.camera_model = camera_model
        self.feature_points = np.array(feature_points, dtype=float).reshape(-1, 3)
        self.noise_px = float(noise_px)
        self.max_residual = acceptance_residual(camera_model, self.noise_px)
        f = camera_model.focal_length
        self._table = projection_table(self.feature_points, f)
        sigma_m = measurement_sigma(self.noise_px, camera_model.pixel_pitch, NOISE_FLOOR_PX)
        self._r = sigma_m**2  # R = sigma_m^2 I (eq. 6)
        self._r_matrix = self._r * np.eye(2 * self.feature_points.shape[0])
        # Q = cov(omega) (eq. 5), diagonal: sigma_a^2 for x, y, z, sigma_alpha^2 for the angles;
        # B Q B' = sum over the blocks (q, q), (q, q_dot), (q_dot, q), (q_dot, q_dot) of a power
        # of t_s times Q placed in that block: the four placements, flattened, (4, 144).
        q = np.array([sigma_acceleration**2] * 3 + [sigma_angular_acceleration**2] * 3)
        q_blocks = np.zeros((4, 12, 12))
        for j, (a, b) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
            q_blocks[j, 6 * a : 6 * a + 6, 6 * b : 6 * b + 6] = np.diag(q)
        self._q_blocks: FloatArray = q_blocks.reshape(4, 144)
        self._p0 = default_initial_covariance()[np.ix_(BLOCK_ORDER, BLOCK_ORDER)]
        m = state_to_global(camera_model.rotation)[:, BLOCK_ORDER]  # (6, 12), eqs. 11-12
        self._to_global, self._to_global_t = m, np.ascontiguousarray(m.T)
        self.x = np.zeros((self.n, 12))
        self.P = np.tile(self._p0, (self.n, 1, 1))
        self.initialised = np.zeros(self.n, dtype=bool)
        self.diverged = np.zeros(self.n, dtype=bool)
        self.high_nis = np.zeros(self.n, dtype=np.int64)
        self.reinitialisations = np.zeros(self.n, dtype=np.int64)
        self._status = np.full(self.n, INITIALISING, dtype=np.int8)
        self._env = np.arange(self.n)

    # -- public -------------------------------------------------------------------------------
    def reset(self, which: NDArray[np.bool_] | None = None) -> None:
        """Forget everything for the envs ``which`` (all if None): their next accepted frame
        initialises again (``TargetEstimator.reset``)."""
        rows = slice(None) if which is None else np.asarray(which, dtype=bool).reshape(self.n)
        self.initialised[rows] = False
        self.diverged[rows] = False
        self.high_nis[rows] = 0
        self.reinitialisations[rows] = 0
        self._status[rows] = INITIALISING

    def snapshot(self, rows: ArrayLike) -> FilterRows:
        """The state of the filters ``rows`` (indices), a copy (`FilterRows`)."""
        idx = np.asarray(rows, dtype=np.intp)
        return FilterRows(
            self.x[idx],
            self.P[idx],
            self.initialised[idx],
            self.diverged[idx],
            self.high_nis[idx],
            self.reinitialisations[idx],
            self._status[idx],
        )

    def restore(self, rows: ArrayLike, state: FilterRows) -> None:
        """Give the filters ``rows`` (indices, as many as ``state`` has) the state ``state``:
        their next update is the one the snapshot's filters would have made."""
        idx = np.asarray(rows, dtype=np.intp)
        self.x[idx], self.P[idx] = state.x, state.P
        self.initialised[idx], self.diverged[idx] = state.initialised, state.diverged
        self.high_nis[idx] = state.high_nis
        self.reinitialisations[idx] = state.reinitialisations
        self._status[idx] = state.status

    @property
    def state(self) -> FloatArray:
        """X (n, 12) in the paper's order (x, x_dot, y, y_dot, ...), a copy."""
        return self.x[:, PAPER_ORDER]

    @property
    def covariance(self) -> FloatArray:
        """P (n, 12, 12) in the paper's order, a copy."""
        return self.P[:, PAPER_ORDER[:, None], PAPER_ORDER]

    def update(
        self,
        images: ArrayLike,
        dt: ArrayLike,
        active: ArrayLike | None = None,
    ) -> BatchedEstimates:
        """One step of every active estimator.

        Args:
            images: (n, N, 2) measured ``[x_m, z_m]`` per env, metres; NaN rows for points not
                seen, which a running filter leaves out of its update (``partial_frames``, as
                ``TargetEstimator``; every row NaN: no frame this step).
            dt: (n,) time since each env's previous step, s (a scalar applies to all).
            active: (n,) bool, the envs to step (default all); the others keep their state.

        Returns:
            The `BatchedEstimates` of the step.
        """
        n, n_points = self.n, self.feature_points.shape[0]
        z = np.asarray(images, dtype=float)
        if z.shape != (n, n_points, 2):
            raise ValueError(f"images must have shape {(n, n_points, 2)}, got {z.shape}")
        dts = np.broadcast_to(np.asarray(dt, dtype=float), (n,))
        act = np.ones(n, dtype=bool) if active is None else np.asarray(active, dtype=bool)
        if act.shape != (n,):
            raise ValueError(f"active must have shape {(n,)}, got {act.shape}")
        if (dts < 0).any() and (dts[act] < 0).any():
            raise ValueError(f"dt must be >= 0, got {dts[act].min()}")
        # A finite sum proves every entry finite (one reduction instead of two).
        has_frame = np.isfinite(z.sum(axis=(1, 2)))
        complete = has_frame  # every point seen: a frame photogrammetry can initialise from
        if not has_frame.all():
            seen = np.isfinite(z).all(axis=2)  # (n, N): a point is seen with both coordinates
            complete = seen.all(axis=1)
            has_frame = seen.any(axis=1) if self.partial_frames == "update" else complete
            if has_frame.any() and not complete[has_frame].all():
                z = np.where(seen[:, :, None], z, np.nan)
        running = act & self.initialised & ~self.diverged
        fails = np.zeros(n, dtype=bool)  # diverged during this step's predict or update
        if running.any():
            self._step_filters(running, z, dts, has_frame, fails)
        # Filters to (re)start from photogrammetry: never initialised, diverged earlier, or now.
        starting = act & ~running | fails
        if starting.any():
            self.diverged |= fails
            self._status[starting] = np.where(self.diverged[starting], DIVERGED, INITIALISING)
            self._try_initialise(starting & complete, z)
        return self._estimates(act)

    # -- steps --------------------------------------------------------------------------------
    def _step_filters(
        self,
        running: BoolArray,
        z: FloatArray,
        dt: FloatArray,
        has_frame: BoolArray,
        fails: BoolArray,
    ) -> None:
        """Predict the running filters, update those with a frame; mark the divergences in
        ``fails`` (``TargetEstimator._update_ekf`` up to its calls of ``_declare_diverged``)."""
        run = _rows(running)
        env = self._env[run]  # env numbers of the running filters
        x, p = self.x[run], self.P[run]  # views when every env runs, else copies
        self._predict(x, p, dt[run])
        frame = has_frame[run]
        seen = _rows(frame)  # rows of x, p with a frame
        if isinstance(seen, np.ndarray):  # predict-only: diverged when not finite
            blind = ~frame
            finite = np.isfinite(x[blind].sum(axis=1) + p[blind].sum(axis=(1, 2)))
            self._status[env[blind]] = PREDICTING
            fails[env[blind]] = ~finite
        if not isinstance(seen, np.ndarray) or seen.size:
            env_seen = env[seen]
            x_new, p_new, factored, nis, in_front = self._update(x[seen], p[seen], z[env_seen])
            # Where S could not be factored the single filter raises before changing anything
            # and diverges; its state is never read again, so x_new, p_new may be kept there.
            high_nis = self.high_nis[env_seen]
            high_nis = np.where(~factored, high_nis, np.where(nis > NIS_LIMIT, high_nis + 1, 0))
            self.high_nis[env_seen] = high_nis
            finite = np.isfinite(x_new.sum(axis=1) + p_new.sum(axis=(1, 2)))
            good = factored & (high_nis < DIVERGENCE_FRAMES) & in_front & finite
            self._status[env_seen] = OK
            fails[env_seen] = ~good
            if isinstance(run, slice) and isinstance(seen, slice):  # every env: no copy
                self.x, self.P = x_new, p_new
                return
            x[seen], p[seen] = x_new, p_new
        if isinstance(run, np.ndarray):
            self.x[run], self.P[run] = x, p

    def _predict(self, x: FloatArray, p: FloatArray, dt: FloatArray) -> None:
        """Eqs. 3-5 in place: ``X = A X``, ``P = A P A' + B Q B'`` with ``A = I + t_s shift``."""
        t = dt[:, None]
        x[:, :6] += t * x[:, 6:]  # q += t_s q_dot
        t = t[:, :, None]
        p[:, :6, :] += t * p[:, 6:, :]  # A P: rows
        p[:, :, :6] += t * p[:, :, 6:]  # (A P) A': columns
        # + B Q B' with B = (t_s^2 / 2, t_s)' per coordinate: [[t^4/4, t^3/2], [t^3/2, t^2]] (x) Q
        half_t2 = 0.5 * dt * dt
        blocks = np.stack([half_t2 * half_t2, half_t2 * dt, half_t2 * dt, dt * dt], axis=1)
        p += row_stable_matmul(blocks, self._q_blocks).reshape(p.shape)

    def _update(
        self, x: FloatArray, p: FloatArray, images: FloatArray
    ) -> tuple[FloatArray, FloatArray, BoolArray, FloatArray, BoolArray]:
        """Eqs. 6-7 for m filters with frames (m, N, 2), from their priors x (m, 12), p.

        Returns:
            The posteriors x (m, 12) and P (m, 12, 12), angles wrapped; whether S could be
            factored (finite, positive definite; where not, the rest is meaningless); the NIS;
            whether every feature point of the prior lies beyond the lens.
        """
        m, n_z = x.shape[0], 2 * images.shape[1]
        # h(X) and J at the prior (eq. 6), every pose as a row of a matrix-matrix product (a lone
        # pose too): a filter's numbers do not depend on which other filters update this step,
        # so an episode plays the same in any batch (a batch of 20 validation seeds or of 3)
        rj, depth = project_poses(x[:, :6], self._table, 0.0, np.zeros(m, dtype=bool))
        h = rj[:, 0].transpose(0, 2, 1).reshape(m, n_z)  # (x_m1, z_m1, x_m2, ...)
        jac = rj[:, 1:].transpose(0, 3, 2, 1).reshape(m, n_z, 6)  # J = dh/dq: H = [J, 0]
        y = images.reshape(m, n_z) - h  # innovation z - h(X)
        missing = np.isnan(y)
        if missing.any():  # points not seen: their rows of H and of the innovation are zero
            jac[missing] = 0.0
            y[missing] = 0.0
        jac_t = np.ascontiguousarray(jac.transpose(0, 2, 1))
        pht = p[:, :, :6] @ jac_t  # P H' (m, 12, 8)
        s = jac @ pht[:, :6] + self._r_matrix  # S = H P H' + R
        lower, factored = _cholesky(s)
        l_inv = _lower_inverse(lower)
        w = (l_inv @ y[:, :, None])[:, :, 0]  # L^-1 y
        nis = np.einsum("ij,ij->i", w, w)  # y' S^-1 y
        k = pht @ (l_inv.transpose(0, 2, 1) @ l_inv)  # K = P H' S^-1
        x_new = x + (k @ y[:, :, None])[:, :, 0]
        # Joseph form: (I - K H) P (I - K H)' + K R K'.
        hp = np.ascontiguousarray(pht.transpose(0, 2, 1))  # H P = (P H')' (P symmetric)
        a = p - k @ hp  # (I - K H) P
        k_t = np.ascontiguousarray(k.transpose(0, 2, 1))
        p_new = a - (a[:, :, :6] @ jac_t - self._r * k) @ k_t  # a (I - K H)' + K R K'
        angles = x_new[:, _ANGLES]  # a view: keep the Euler angles in [-pi, pi)
        if angles.max() >= math.pi or angles.min() < -math.pi:  # (NaN stays NaN either way)
            outside = (angles >= math.pi) | (angles < -math.pi)
            angles[outside] = wrap_angle(angles[outside])
        return x_new, p_new, factored, nis, depth.min(axis=1) > 0.0

    def _try_initialise(self, which: BoolArray, z: FloatArray) -> None:
        """Initialise the filters ``which`` from accepted cold photogrammetry of their frames."""
        idx = np.flatnonzero(which)
        if idx.size == 0:
            return
        poses, accepted = self.cold_solve(z[idx])
        idx, poses = idx[accepted], poses[accepted]
        self.x[idx] = 0.0
        self.x[idx, :6] = poses  # rates zero
        self.P[idx] = self._p0
        self.reinitialisations[idx] += self.diverged[idx]
        self.initialised[idx] = True
        self.diverged[idx] = False
        self.high_nis[idx] = 0
        self._status[idx] = OK

    def cold_solve(self, images: FloatArray) -> tuple[FloatArray, BoolArray]:
        """Cold photogrammetry (no initial guess) of m images (m, N, 2), metres: poses (m, 6) in
        the camera frame (metres, radians) and which are accepted (m,) (where
        ``TargetEstimator.solve(image, None)`` is not None)."""
        f = self.camera_model.focal_length
        poses, converged, _, rms = solve_pose_batch(images, self.feature_points, f)
        return poses, solution_accepted(converged, rms, self.max_residual)

    def _estimates(self, active: BoolArray) -> BatchedEstimates:
        """Eqs. 11-12: the global-frame estimates; NaN rows where not valid."""
        valid = active & _VALID[self._status]
        m, m_t = self._to_global, self._to_global_t
        pv = row_stable_matmul(self.x, m_t)  # (n, 6): R_gc-rotated (position, velocity)
        cov = m @ self.P @ m_t
        if not valid.all():
            pv[~valid] = np.nan
            cov[~valid] = np.nan
        return BatchedEstimates(
            position=pv[:, :3] + self.camera_model.position,
            velocity=pv[:, 3:],
            covariance=cov,
            valid=valid,
            status=self._status.copy(),
        )
