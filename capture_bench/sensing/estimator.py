"""Target state estimation: photogrammetry -> EKF, output in the global frame (paper section 2).

One estimator, `TargetEstimator`, for n episodes at once, each a row of its arrays (one row for a
single env, one per sub-env or recorded episode otherwise). A row's numbers do not depend on the
other rows of the call (every product is a per-row or per-matrix one), so an episode estimates
the same alone or in any batch. Three sources, chosen by name:

* ``"ekf"`` (the paper): the first frame whose photogrammetry solution is accepted initialises the
  row's filter (that step reports the photogrammetry position, zero velocity and the prior
  covariance); afterwards each step is predict(dt) then update with the frame (a missing frame is
  a predict-only step). A frame in which some feature points were not found (the rendered
  camera's; NaN rows) updates a running filter with the points seen, or is a predict-only step
  with ``partial_frames="predict"``. By default it never initialises (photogrammetry needs every
  point); with ``min_init_markers=3`` a frame of exactly three points may (see below).
* ``"photogrammetry"`` (raw-measurement ablation): the per-frame pose, warm-started from the
  previous solution; velocity by finite difference of consecutive solutions over the time between
  them (zero after the first solution); no covariance. Without a frame the last solution is held.
* ``"truth"`` (privileged ablation): the true position and velocity passed in.

The estimate is moved to the global frame by eqs. 11-12 with the camera fixed (T-dot = 0):
``X_T = c + R_gc p_C``, ``X_T-dot = R_gc v_C``, covariance rotated blockwise.

Acceptance of a photogrammetry solution: converged, and its image residual RMS at most
``ACCEPT_RESIDUAL_SIGMAS`` times the assumed pixel noise (floored like the EKF's R).

Divergence rule (``"ekf"``): a row's filter is declared diverged when its state or covariance
becomes non-finite, when its innovation covariance S is not positive definite, when a feature point
of the predicted state lies behind the lens at an update, or when the NIS of
``DIVERGENCE_FRAMES`` consecutive updates exceeds ``NIS_LIMIT`` (chi-square with 8 degrees of
freedom exceeds 100 with probability below 1e-17). On the step it is detected, and on every later
step with a frame, the estimator tries to re-initialise from photogrammetry of that frame; every
step on which it cannot reports status ``"diverged"`` with ``valid = False``.

Invalid estimates (``"initialising"``, ``"diverged"``) carry NaN position and velocity: the caller
must check ``valid``.

Three-point initialisation (``min_init_markers=3``; the default 4 leaves all of the above as it
is). A row without a running filter whose frame is not complete but shows three or more points:

* if the row holds candidate poses from an earlier three-point frame, each is scored by its image
  residual against this frame's seen points (`capture_bench.sensing.p3p.candidate_residuals`,
  the pose held: the filter starts with zero rates). When exactly one is within the acceptance
  residual (`p3p.pick_candidate`), it is refined by Levenberg-Marquardt on this frame's points
  (`p3p.refine_pose`) and, accepted, initialises the filter as a photogrammetry solution would;
* otherwise, a frame of exactly three points replaces the candidates by its own P3P solutions
  (`p3p.three_point_poses`, those with every point beyond the lens). A single solution
  initialises the filter at once, and so do solutions whose capture points all lie within the
  filter's prior position standard deviation (0.05 m per axis: `ekf.default_initial_covariance`)
  of one of them (`p3p.consensus_candidate`): the filter starts from that one, whatever their
  attitudes. The capture point is what the controllers need, and P3P's solutions mostly differ
  in attitude: a target whose attitude is drawn at random cannot be told apart by a prior on
  it (the two solutions of a three-point frame of ``grasp_rendered``'s validation seeds lie 5 to
  31 mm apart, their attitudes 1-20 degrees). A wrong attitude shows as a large NIS once a
  fourth point is seen, and a diverged filter re-initialises from that complete frame.

Held candidates are the same for the same points seen, so a later frame tells them apart only
when it shows a point the candidates' frame did not (a complete frame initialises by
photogrammetry first). A complete frame, a ``reset`` and an initialisation drop the candidates;
`FilterRows` carries them.

The filter (eqs. 3-7), with its state in blocks ``X = (q, q_dot)``, ``q = (x, y, z, theta_x,
theta_y, theta_z)`` the pose in the camera frame (the paper orders the same 12 numbers ``(x, x_dot,
y, y_dot, ...)``; `TargetEstimator.state` gives that order). In blocks the model's structure is
plain:

* eq. 4: ``A = I + t_s [[0, I], [0, 0]]`` (a shift of the rates into the pose), so ``A P A'`` is
  two in-place row/column operations;
* eq. 5: ``B Q B' = [[t_s^4/4, t_s^3/2], [t_s^3/2, t_s^2]] (x) diag(sigma_a^2 I_3,
  sigma_alpha^2 I_3)``, 24 entries;
* eq. 6: ``H = [J, 0]`` with J (8, 6) the analytic Jacobian of the image points in the pose
  (`capture_bench.sensing.photogrammetry.project_poses`), so ``P H' = P[:, :6] J'``;
* eq. 7: ``S = H P H' + R`` (its Cholesky factorisation is the positive-definiteness test),
  ``S^-1 [y, H P]`` by one solve, ``K = P H' S^-1``, ``X += K y``, the NIS ``y' S^-1 y``, and the
  Joseph form ``P = (I - K H) P (I - K H)' + K R K'``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.ekf import (
    NOISE_FLOOR_PX,
    POSE_INDEX,
    POSITION_VELOCITY_INDEX,
    default_initial_covariance,
    measurement_sigma,
    wrap_angle,
)
from capture_bench.sensing.p3p import (
    MAX_CANDIDATES,
    candidate_residuals,
    consensus_candidate,
    pick_candidate,
    refine_pose,
    three_point_poses,
)
from capture_bench.sensing.photogrammetry import (
    PoseSolution,
    project_poses,
    projection_table,
    solve_poses,
)
from capture_bench.sensing.sources import SOURCES

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

STATUSES = ("ok", "predicting", "initialising", "diverged")
OK, PREDICTING, INITIALISING, DIVERGED = range(len(STATUSES))
_VALID = np.array([s in ("ok", "predicting") for s in STATUSES])  # status -> estimate valid
#: What the EKF does with a frame missing some feature points (see the module docstring).
PARTIAL_FRAME_RULES = ("update", "predict")
NIS_LIMIT = 100.0
DIVERGENCE_FRAMES = 5
ACCEPT_RESIDUAL_SIGMAS = 5.0

# Block state (q, q_dot) -> paper order: X_paper[BLOCK_ORDER] = X_block.
BLOCK_ORDER = np.concatenate([POSE_INDEX, POSE_INDEX + 1])
PAPER_ORDER = np.argsort(BLOCK_ORDER)  # X_block[PAPER_ORDER] = X_paper
_ANGLES = slice(3, 6)  # theta_x, theta_y, theta_z in the block state
# The 24 entries of B Q B' (eq. 5) in the block state: for each coordinate i of q, (i, i),
# (i, i + 6), (i + 6, i) and (i + 6, i + 6), with the power of t_s and the factor of each.
_BQB_ROWS = np.repeat(np.arange(6), 4) + np.tile([0, 0, 6, 6], 6)
_BQB_COLS = np.repeat(np.arange(6), 4) + np.tile([0, 6, 0, 6], 6)
_BQB_POWER = np.tile([4.0, 3.0, 3.0, 2.0], 6)
_BQB_FACTOR = np.tile([0.25, 0.5, 0.5, 1.0], 6)


def acceptance_residual(
    camera_model: CameraModel, noise_px: float, noise_floor_px: float = NOISE_FLOOR_PX
) -> float:
    """Largest accepted photogrammetry residual RMS, metres on the image plane."""
    sigma_m = measurement_sigma(noise_px, camera_model.pixel_pitch, noise_floor_px)
    return ACCEPT_RESIDUAL_SIGMAS * sigma_m


def solution_accepted(converged: ArrayLike, residual_rms: ArrayLike, max_residual: float) -> Any:
    """The acceptance rule: converged with residual RMS <= ``max_residual`` (scalars or arrays)."""
    return np.logical_and(converged, np.less_equal(residual_rms, max_residual))


def state_to_global(rotation: FloatArray) -> FloatArray:
    """EKF state X (12,) in the paper's order -> global-frame (position, velocity) less the
    camera position, (6, 12).

    ``blockdiag(R_gc, R_gc) @ S`` with S selecting (x, y, z, x_dot, y_dot, z_dot) from X
    (eqs. 11-12, T-dot = 0); add the camera position to the first three rows' result.
    """
    select = np.zeros((6, 12))
    select[np.arange(6), POSITION_VELOCITY_INDEX] = 1.0
    rot6 = np.zeros((6, 6))
    rot6[:3, :3] = rot6[3:, 3:] = rotation
    return rot6 @ select


@dataclass
class Estimates:
    """One step of n estimators, global frame.

    Attributes:
        position: capture point, m, (n, 3); NaN where not valid.
        velocity: capture point velocity, m/s, (n, 3); NaN where not valid.
        covariance: (n, 6, 6) covariance of (position, velocity); NaN where not valid or where the
            source has none (photogrammetry, truth).
        valid: (n,) whether position and velocity hold an estimate.
        status: (n,) int8 index into `STATUSES`: "ok" (a frame was used this step),
            "predicting" (no frame this step; the estimate is a prediction or the held last
            solution), "initialising" (no accepted photogrammetry yet), or "diverged".

    Rows not active in the step carry no estimate (NaN, not valid) and their previous status.
    """

    position: FloatArray
    velocity: FloatArray
    covariance: FloatArray
    valid: BoolArray
    status: NDArray[np.int8]

    def status_names(self) -> list[str]:
        """The statuses as strings of `STATUSES`."""
        return [STATUSES[s] for s in self.status]


@dataclass
class FilterRows:
    """The complete state of m rows of a `TargetEstimator`: what their next `update` reads,
    so that another estimator given it (`TargetEstimator.restore`) continues those rows bit for
    bit.

    Attributes:
        x: (m, 12) states, block order, camera frame; P: (m, 12, 12) their covariances.
        initialised, diverged: (m,) flags; high_nis, reinitialisations: (m,) counters;
        status: (m,) int8 index into `STATUSES`; elapsed: (m,) s since the last accepted
        photogrammetry solution (the photogrammetry source's).
        candidates: (m, MAX_CANDIDATES, 6) the held three-point candidate poses, NaN rows for
            none (see the module docstring); None: none held (filled with NaN).
    """

    x: FloatArray
    P: FloatArray
    initialised: BoolArray
    diverged: BoolArray
    high_nis: NDArray[np.int64]
    reinitialisations: NDArray[np.int64]
    status: NDArray[np.int8]
    elapsed: FloatArray
    candidates: FloatArray | None = None

    def __post_init__(self) -> None:
        if self.candidates is None:
            self.candidates = np.full((len(self.x), MAX_CANDIDATES, 6), np.nan)

    @classmethod
    def stack(cls, parts: list[FilterRows]) -> FilterRows:
        """The rows of ``parts``, in order, as one `FilterRows`."""
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)))


def _rows(mask: BoolArray) -> slice | NDArray[np.intp]:
    """Index of the True rows: a slice (a view, no copy) when all are."""
    return slice(None) if mask.all() else np.flatnonzero(mask)


def _solve_innovations(s: FloatArray, rhs: FloatArray) -> tuple[FloatArray, BoolArray]:
    """``S^-1 rhs`` for m innovation covariances S (m, k, k), and which S are finite and
    positive definite (their Cholesky factorisation exists); where one is not, its solution is
    meaningless (the filter diverges)."""
    try:
        np.linalg.cholesky(s)
        return np.linalg.solve(s, rhs), np.ones(s.shape[0], dtype=bool)
    except np.linalg.LinAlgError:  # rare: find the failures one by one, solve the rest
        ok = np.isfinite(s.sum(axis=(1, 2)))
        for i in np.flatnonzero(ok).tolist():
            try:
                np.linalg.cholesky(s[i])
            except np.linalg.LinAlgError:
                ok[i] = False
        s = np.where(ok[:, None, None], s, np.eye(s.shape[-1]))
        return np.linalg.solve(s, rhs), ok


class TargetEstimator:
    """n estimators of the capture point's global-frame state from camera frames, one per row.

    Args:
        n: number of rows (episodes).
        camera_model: the (fixed) camera's geometry, shared by all rows.
        feature_points: feature points in the target frame, metres, shape (N, 3).
        source: "ekf", "photogrammetry" or "truth".
        noise_px: image noise the estimators assume, pixels (sets R and acceptance).
        sigma_acceleration: EKF process noise sigma_a, m/s^2.
        sigma_angular_acceleration: EKF process noise sigma_alpha, rad/s^2.
        partial_frames: what the ``"ekf"`` source does with a frame in which some feature points
            were not found (NaN rows; the rendered camera's): ``"update"`` (default) corrects a
            running filter with the points seen, ``"predict"`` treats the frame as lost (a
            predict-only step). Either way such a frame cannot initialise the filter unless
            ``min_init_markers`` allows it.
        min_init_markers: fewest feature points of a frame that may initialise the ``"ekf"``
            source's filter: the number of feature points (the default, 4: photogrammetry of
            complete frames only) or 3 (also three-point initialisation, see the module
            docstring).
        noise_floor_px: R and the acceptance use ``max(noise_px, noise_floor_px)``, pixels:
            the default keeps a noise-free camera's filter well conditioned; a camera whose
            error was measured (the rendered one's, `Scenario.estimator_settings`) passes 0.

    Attributes:
        x: (n, 12) states in block order ``(q, q_dot)`` (see the module docstring), camera frame
            (the photogrammetry source: the last solution's pose and the finite-difference
            velocity).
        P: (n, 12, 12) their covariances, block order. ``update`` may replace both arrays (read
            them after the call rather than keeping references).
        initialised: (n,) whether the row has an estimate (a filter or a solution) to go on from.
        diverged: (n,) whether the row's filter diverged and has not re-initialised yet.
        high_nis: (n,) consecutive updates with NIS > ``NIS_LIMIT``.
        reinitialisations: (n,) times each filter restarted after a divergence.
    """

    def __init__(
        self,
        n: int,
        camera_model: CameraModel,
        feature_points: ArrayLike,
        source: str = "ekf",
        noise_px: float = 1.0,
        sigma_acceleration: float = 0.01,
        sigma_angular_acceleration: float = 0.01,
        partial_frames: str = "update",
        min_init_markers: int = 4,
        noise_floor_px: float = NOISE_FLOOR_PX,
    ) -> None:
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        if source not in SOURCES:
            raise ValueError(f"unknown estimator source {source!r}; valid sources: {SOURCES}")
        if partial_frames not in PARTIAL_FRAME_RULES:
            raise ValueError(
                f"unknown partial_frames {partial_frames!r}; valid: {PARTIAL_FRAME_RULES}"
            )
        self.n = int(n)
        self.source = source
        self.partial_frames = partial_frames
        self.camera_model = camera_model
        self.feature_points = np.array(feature_points, dtype=float).reshape(-1, 3)
        n_points = self.feature_points.shape[0]
        if min_init_markers not in (3, n_points):
            raise ValueError(
                f"min_init_markers must be 3 or the number of feature points ({n_points}), "
                f"got {min_init_markers}"
            )
        self.min_init_markers = int(min_init_markers)
        # Per row: the candidate poses of its latest three-point frame, NaN rows for none.
        self._candidates = np.full((self.n, MAX_CANDIDATES, 6), np.nan)
        self.noise_px = float(noise_px)
        if not noise_floor_px >= 0.0:
            raise ValueError(f"noise_floor_px must be >= 0, got {noise_floor_px}")
        # image plane, m
        self.max_residual = acceptance_residual(camera_model, self.noise_px, noise_floor_px)
        self._table = projection_table(self.feature_points, camera_model.focal_length)
        sigma_m = measurement_sigma(self.noise_px, camera_model.pixel_pitch, noise_floor_px)
        self._r = sigma_m**2  # R = sigma_m^2 I (eq. 6)
        self._r_matrix = self._r * np.eye(2 * self.feature_points.shape[0])
        # Q = cov(omega) (eq. 5), diagonal: sigma_a^2 for x, y, z, sigma_alpha^2 for the angles.
        q = np.array([sigma_acceleration**2] * 3 + [sigma_angular_acceleration**2] * 3)
        self._bqb_factor = _BQB_FACTOR * np.repeat(q, 4)
        self._p0 = default_initial_covariance()[np.ix_(BLOCK_ORDER, BLOCK_ORDER)]
        # Three-point consensus: the prior's position standard deviations; the attitude free.
        self._consensus_spread = np.concatenate([np.sqrt(np.diag(self._p0)[:3]), [np.inf] * 3])
        m = state_to_global(camera_model.rotation)[:, BLOCK_ORDER]  # (6, 12), eqs. 11-12
        self._to_global, self._to_global_t = m, np.ascontiguousarray(m.T)
        self.x = np.zeros((self.n, 12))
        self.P = np.tile(self._p0, (self.n, 1, 1))
        self.initialised = np.zeros(self.n, dtype=bool)
        self.diverged = np.zeros(self.n, dtype=bool)
        self.high_nis = np.zeros(self.n, dtype=np.int64)
        self.reinitialisations = np.zeros(self.n, dtype=np.int64)
        self._elapsed = np.zeros(self.n)
        self._status = np.full(self.n, INITIALISING, dtype=np.int8)
        self._row = np.arange(self.n)
        self._all = np.ones(self.n, dtype=bool)

    # -- public -------------------------------------------------------------------------------
    def reset(self, which: ArrayLike | None = None) -> None:
        """Forget everything for the rows ``which`` (bool (n,); all if None): their next accepted
        frame initialises again."""
        rows = slice(None) if which is None else np.asarray(which, dtype=bool).reshape(self.n)
        self.x[rows] = 0.0
        self.initialised[rows] = False
        self.diverged[rows] = False
        self.high_nis[rows] = 0
        self.reinitialisations[rows] = 0
        self._elapsed[rows] = 0.0
        self._status[rows] = INITIALISING
        self._candidates[rows] = np.nan

    def snapshot(self, rows: ArrayLike) -> FilterRows:
        """The state of the rows ``rows`` (indices), a copy (`FilterRows`)."""
        idx = np.asarray(rows, dtype=np.intp)
        return FilterRows(
            self.x[idx],
            self.P[idx],
            self.initialised[idx],
            self.diverged[idx],
            self.high_nis[idx],
            self.reinitialisations[idx],
            self._status[idx],
            self._elapsed[idx],
            self._candidates[idx],
        )

    def restore(self, rows: ArrayLike, state: FilterRows) -> None:
        """Give the rows ``rows`` (indices, as many as ``state`` has) the state ``state``: their
        next update is the one the snapshot's rows would have made."""
        idx = np.asarray(rows, dtype=np.intp)
        self.x[idx], self.P[idx] = state.x, state.P
        self.initialised[idx], self.diverged[idx] = state.initialised, state.diverged
        self.high_nis[idx] = state.high_nis
        self.reinitialisations[idx] = state.reinitialisations
        self._status[idx] = state.status
        self._elapsed[idx] = state.elapsed
        self._candidates[idx] = state.candidates

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
        truth: tuple[ArrayLike, ArrayLike] | None = None,
    ) -> Estimates:
        """One step of every active row.

        Args:
            images: (n, N, 2) measured ``[x_m, z_m]`` per row, metres; NaN rows for points not
                seen (``partial_frames``; every row NaN: no frame this step).
            dt: (n,) time since each row's previous step, s (a scalar applies to all).
            active: (n,) bool, the rows to step (default all); the others keep their state.
            truth: the true capture point's position and velocity, global, m and m/s, (n, 3)
                each: what the ``"truth"`` source reports (required there, read nowhere else).

        Returns:
            The `Estimates` of the step.
        """
        n, n_points = self.n, self.feature_points.shape[0]
        z = np.asarray(images, dtype=float)
        if z.shape != (n, n_points, 2):
            raise ValueError(f"images must have shape {(n, n_points, 2)}, got {z.shape}")
        dts = np.asarray(dt, dtype=float)
        if dts.shape != (n,):
            dts = np.broadcast_to(dts, (n,))
        act = self._all if active is None else np.asarray(active, dtype=bool)
        if act.shape != (n,):
            raise ValueError(f"active must have shape {(n,)}, got {act.shape}")
        if n == 1 and act[0] and self.source == "ekf":
            return self._update_one(z, dts)
        if (dts < 0).any() and (dts[act] < 0).any():
            raise ValueError(f"dt must be >= 0, got {dts[act].min()}")
        if self.source == "truth":
            return self._truth(act, truth)
        # A finite sum proves every entry finite (one reduction instead of two).
        has_frame = np.isfinite(z.sum(axis=(1, 2)))
        complete = has_frame  # every point seen: a frame photogrammetry can initialise from
        if not has_frame.all():
            seen = np.isfinite(z).all(axis=2)  # (n, N): a point is seen with both coordinates
            complete = seen.all(axis=1)
            has_frame = seen.any(axis=1) if self.partial_frames == "update" else complete
            if has_frame.any() and not complete[has_frame].all():
                z = np.where(seen[:, :, None], z, np.nan)
        if self.source == "photogrammetry":
            self._photogrammetry(act, z, dts, complete)
            return self._estimates(act)
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
            if self.min_init_markers < n_points:
                self._try_three_point(starting & ~complete, z)
        return self._estimates(act)

    def cold_solve(self, images: FloatArray) -> tuple[FloatArray, BoolArray]:
        """Cold photogrammetry (no initial guess, memoised: `solve_poses`) of m images (m, N, 2),
        metres: poses (m, 6) in the camera frame (metres, radians) and which are accepted (m,)."""
        solutions = solve_poses(images, self.feature_points, self.camera_model.focal_length)
        poses = np.array([s.pose for s in solutions]).reshape(-1, 6)
        return poses, self._accepted(solutions)

    # -- the EKF ------------------------------------------------------------------------------
    def _update_one(self, z: FloatArray, dt: FloatArray) -> Estimates:
        """`update` of a one-row EKF, every row active: the same kernels on the same (1, ...)
        arrays (so the same numbers as the row in any batch), without the masks and index
        arrays of many rows."""
        if dt[0] < 0:
            raise ValueError(f"dt must be >= 0, got {dt[0]}")
        complete = has_frame = math.isfinite(z.sum())
        if not complete:
            seen = np.isfinite(z).all(axis=2)
            has_frame = self.partial_frames == "update" and bool(seen.any())
            if has_frame:
                z = np.where(seen[:, :, None], z, np.nan)
        fails = False
        running = bool(self.initialised[0]) and not self.diverged[0]
        if running:
            x, p = self.x, self.P
            self._predict(x, p, dt)
            if has_frame:
                x_new, p_new, factored, nis, in_front = self._update(x, p, z)
                high = int(self.high_nis[0])
                if factored[0]:
                    high = high + 1 if nis[0] > NIS_LIMIT else 0
                self.high_nis[0] = high
                finite = math.isfinite(x_new.sum() + p_new.sum())
                self._status[0] = OK
                fails = not (factored[0] and high < DIVERGENCE_FRAMES and in_front[0] and finite)
                self.x, self.P = x_new, p_new
            else:
                self._status[0] = PREDICTING
                fails = not math.isfinite(x.sum() + p.sum())
        if not running or fails:
            diverged = bool(self.diverged[0]) or fails
            self.diverged[0] = diverged
            self._status[0] = DIVERGED if diverged else INITIALISING
            if complete:
                self._try_initialise(self._all, z)
            elif self.min_init_markers < self.feature_points.shape[0]:
                self._try_three_point(self._all, z)
        return self._estimates(self._all)

    def _step_filters(
        self,
        running: BoolArray,
        z: FloatArray,
        dt: FloatArray,
        has_frame: BoolArray,
        fails: BoolArray,
    ) -> None:
        """Predict the running filters, update those with a frame; mark the divergences in
        ``fails``."""
        run = _rows(running)
        row = self._row[run]  # row numbers of the running filters
        x, p = self.x[run], self.P[run]  # views when every row runs, else copies
        self._predict(x, p, dt[run])
        frame = has_frame[run]
        seen = _rows(frame)  # rows of x, p with a frame
        if isinstance(seen, np.ndarray):  # predict-only: diverged when not finite
            blind = ~frame
            finite = np.isfinite(x[blind].sum(axis=1) + p[blind].sum(axis=(1, 2)))
            self._status[row[blind]] = PREDICTING
            fails[row[blind]] = ~finite
        if not isinstance(seen, np.ndarray) or seen.size:
            row_seen = row[seen]
            x_new, p_new, factored, nis, in_front = self._update(x[seen], p[seen], z[row_seen])
            # Where S is not positive definite the row diverges; its state is never read again,
            # so x_new, p_new may be kept there.
            high_nis = self.high_nis[row_seen]
            high_nis = np.where(~factored, high_nis, np.where(nis > NIS_LIMIT, high_nis + 1, 0))
            self.high_nis[row_seen] = high_nis
            finite = np.isfinite(x_new.sum(axis=1) + p_new.sum(axis=(1, 2)))
            good = factored & (high_nis < DIVERGENCE_FRAMES) & in_front & finite
            self._status[row_seen] = OK
            fails[row_seen] = ~good
            if isinstance(run, slice) and isinstance(seen, slice):  # every row: no copy
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
        p[:, _BQB_ROWS, _BQB_COLS] += dt[:, None] ** _BQB_POWER * self._bqb_factor

    def _update(
        self, x: FloatArray, p: FloatArray, images: FloatArray
    ) -> tuple[FloatArray, FloatArray, BoolArray, FloatArray, BoolArray]:
        """Eqs. 6-7 for m filters with frames (m, N, 2), from their priors x (m, 12), p.

        Returns:
            The posteriors x (m, 12) and P (m, 12, 12), angles wrapped; whether S is positive
            definite (where not, the rest is meaningless); the NIS; whether every feature point of
            the prior lies beyond the lens.
        """
        m, n_z = x.shape[0], 2 * images.shape[1]
        # h(X) and J at the prior (eq. 6), each pose by its own matrix-vector product: a filter's
        # numbers do not depend on which other filters update this step.
        rj, depth = project_poses(x[:, :6], self._table, 0.0, self._all[:m])  # each pose alone
        h = rj[:, 0].transpose(0, 2, 1).reshape(m, n_z)  # (x_m1, z_m1, x_m2, ...)
        jac = rj[:, 1:].transpose(0, 3, 2, 1).reshape(m, n_z, 6)  # J = dh/dq: H = [J, 0]
        y = images.reshape(m, n_z) - h  # innovation z - h(X)
        if not math.isfinite(y.sum()):  # points not seen: their rows of H and y are zero
            missing = np.isnan(y)
            jac[missing] = 0.0
            y[missing] = 0.0
        pht = p[:, :, :6] @ jac.transpose(0, 2, 1)  # P H' (m, 12, n_z)
        s = jac @ pht[:, :6] + self._r_matrix  # S = H P H' + R
        rhs = np.concatenate((y[:, :, None], pht.transpose(0, 2, 1)), axis=2)  # [y, H P]
        solved, factored = _solve_innovations(s, rhs)  # S^-1 [y, H P]
        nis = np.einsum("ij,ij->i", y, solved[:, :, 0])  # y' S^-1 y
        k = solved[:, :, 1:].transpose(0, 2, 1)  # K = P H' S^-1 = (S^-1 H P)' (m, 12, n_z)
        x_new = x + (k @ y[:, :, None])[:, :, 0]
        # Joseph form: (I - K H) P (I - K H)' + K R K'.
        k_t = solved[:, :, 1:]
        a = p - k @ rhs[:, :, 1:]  # (I - K H) P
        p_new = a - (a[:, :, :6] @ jac.transpose(0, 2, 1) - self._r * k) @ k_t
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
        if idx.size == 0:
            return
        self._start_filters(idx, poses)

    def _start_filters(self, idx: NDArray[np.intp], poses: FloatArray) -> None:
        """Start the filters of rows ``idx`` at poses (m, 6), zero rates, the prior covariance."""
        if self.min_init_markers < self.feature_points.shape[0]:
            self._candidates[idx] = np.nan
        self.x[idx] = 0.0
        self.x[idx, :6] = poses  # rates zero
        self.P[idx] = self._p0
        self.reinitialisations[idx] += self.diverged[idx]
        self.initialised[idx] = True
        self.diverged[idx] = False
        self.high_nis[idx] = 0
        self._status[idx] = OK

    def _try_three_point(self, which: BoolArray, z: FloatArray) -> None:
        """Three-point initialisation of the rows ``which`` (no running filter, frame not
        complete; see the module docstring): pick among held candidates with this frame, else
        take this frame's P3P candidates, starting the filter from a pick or a consensus."""
        seen = np.isfinite(z).all(axis=2)  # (n, N)
        rows = np.flatnonzero(which & (seen.sum(axis=1) >= 3))
        f = self.camera_model.focal_length
        for i in rows.tolist():
            pose = self._picked_candidate(i, z[i])
            if pose is None and np.count_nonzero(seen[i]) == 3:
                candidates = three_point_poses(z[i][seen[i]], self.feature_points[seen[i]], f)
                self._candidates[i] = np.nan
                self._candidates[i, : candidates.shape[0]] = candidates
                if candidates.shape[0]:
                    k = consensus_candidate(candidates, self._consensus_spread)
                    pose = None if k is None else candidates[k]
            if pose is not None:
                self._start_filters(np.array([i]), pose[None])

    def _picked_candidate(self, i: int, image: FloatArray) -> FloatArray | None:
        """Row i's held candidate that this frame (N, 2, NaN where not seen) singles out, refined
        on the frame and accepted; None when there is none."""
        held = self._candidates[i]
        held = held[np.isfinite(held[:, 0])]
        if held.shape[0] == 0:
            return None
        f = self.camera_model.focal_length
        residuals = candidate_residuals(held, image, self.feature_points, f)
        k = pick_candidate(residuals, self.max_residual)
        if k is None:
            return None
        pose, converged, rms = refine_pose(held[k], image, self.feature_points, f)
        return pose if converged and rms <= self.max_residual else None

    # -- the ablations ------------------------------------------------------------------------
    def _photogrammetry(
        self, active: BoolArray, z: FloatArray, dt: FloatArray, complete: BoolArray
    ) -> None:
        """Each active row's pose from its frame, warm-started from its last solution (retried
        cold when that is rejected: a warm start may sit in a wrong local minimum), the velocity
        by finite difference over the time since that solution; without an accepted solution the
        last one is held ("predicting")."""
        poses = self._accepted_poses(np.flatnonzero(active & complete), z)
        for i in np.flatnonzero(active).tolist():
            self._elapsed[i] += dt[i]
            held = bool(self.initialised[i])
            pose = poses.get(i)
            if pose is None:
                self._status[i] = PREDICTING if held else INITIALISING
                continue
            if held and self._elapsed[i] > 0:
                self.x[i, 6:9] = (pose[:3] - self.x[i, :3]) / self._elapsed[i]
            self.x[i, :6] = pose
            self._elapsed[i] = 0.0
            self.initialised[i] = True
            self._status[i] = OK

    def _accepted_poses(self, rows: NDArray[np.int_], z: FloatArray) -> dict[int, FloatArray]:
        """The accepted photogrammetry of the frames of ``rows`` (complete), by row: warm from
        the rows' last solutions (cold where a row has none), all in one solve; a rejected warm
        solution retried cold (a warm start may sit in a wrong local minimum), all in one."""
        if rows.size == 0:
            return {}
        f = self.camera_model.focal_length
        held = self.initialised[rows]
        guesses = np.where(held[:, None], self.x[rows, :6], np.nan)
        solutions = solve_poses(z[rows], self.feature_points, f, guesses)
        retry = np.flatnonzero(held & ~self._accepted(solutions))
        if retry.size:
            again = solve_poses(z[rows[retry]], self.feature_points, f)
            for j, solution in zip(retry.tolist(), again, strict=True):
                solutions[j] = solution
        ok = self._accepted(solutions)
        return {int(i): s.pose for i, s, good in zip(rows, solutions, ok, strict=True) if good}

    def _accepted(self, solutions: list[PoseSolution]) -> BoolArray:
        """Which solutions the acceptance rule keeps (converged, plausible residual)."""
        converged = np.array([s.converged for s in solutions], dtype=bool)
        rms = np.array([s.residual_rms for s in solutions], dtype=float)
        return np.asarray(solution_accepted(converged, rms, self.max_residual), dtype=bool)

    def _truth(self, active: BoolArray, truth: tuple[ArrayLike, ArrayLike] | None) -> Estimates:
        """The true state, valid and "ok", no covariance, on the active rows."""
        if truth is None:
            raise ValueError('the "truth" source needs truth=(position, velocity), (n, 3) each')
        position = np.array(truth[0], dtype=float).reshape(self.n, 3)
        velocity = np.array(truth[1], dtype=float).reshape(self.n, 3)
        self._status[active] = OK
        if not active.all():
            position[~active] = velocity[~active] = np.nan
        return Estimates(
            position, velocity, np.full((self.n, 6, 6), np.nan), active.copy(), self._status.copy()
        )

    def _estimates(self, active: BoolArray) -> Estimates:
        """Eqs. 11-12: the global-frame estimates of the state rows; NaN rows where not valid
        (and the covariance where the source has none)."""
        valid = active & _VALID[self._status]
        m, m_t = self._to_global, self._to_global_t
        pv = (self.x[:, None, :] @ m_t)[:, 0]  # (n, 6): R_gc-rotated (position, velocity)
        if self.source == "ekf":
            cov = m @ self.P @ m_t
        else:
            cov = np.full((self.n, 6, 6), np.nan)
        if not valid.all():
            pv[~valid] = np.nan
            cov[~valid] = np.nan
        return Estimates(
            position=pv[:, :3] + self.camera_model.position,
            velocity=pv[:, 3:],
            covariance=cov,
            valid=valid,
            status=self._status.copy(),
        )
