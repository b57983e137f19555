"""The target's side of an episode as one record type, `RecordedEpisode`, and its batched
recording, many episodes at once (for ``CaptureVectorEnv``).

`RecordedEpisode` is what both envs consume, live or replayed
(`capture_bench.task.target_side` fills one step by step for ``CaptureEnv``): the true state
(the trajectory, paper section 4), the camera's frames (eq. 2), the estimates in the global frame
(EKF eqs. 3-7, 11-12), their errors and NEES (`estimate_errors`), and reachability.

Nothing on the target's side of a step depends on the agent's actions: the trajectory and control
periods are drawn
at reset, the camera's noise and drop-outs come from the episode's generator in a fixed order, and
the estimator sees only the frames. So an episode's target side can be computed for its whole
horizon at reset, and the target sides of many episodes can be computed together: the true states
and the camera vectorised over time
(`capture_sequence`), the EKF over episodes
(`TargetEstimator`, a row per episode), the bound over episodes
(`episode_bounds`). Each episode draws from its own generator
exactly what ``CaptureEnv(reuse_target_side=True)`` draws, in the same order.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from capture_bench.sensing.camera import Camera
from capture_bench.sensing.estimator import FilterRows, TargetEstimator
from capture_bench.sim import kinematics
from capture_bench.task.episode import EpisodePlan, draw_plans, episode_bounds
from capture_bench.task.observation import TaskDescription
from capture_bench.task.physical_limit import PhysicalLimit
from capture_bench.task.scenarios import Scenario

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(eq=False)
class EpisodeTruth:
    """An episode's plan, the time and real period of reset (0) and of every step k, the true
    state there and the camera's frames: ``time``, ``dt`` (T+1,), s; ``position``, ``velocity``
    (T+1, 3) true X_T and its rate; ``rotation`` (T+1, 3, 3) R_gt; ``images`` (T+1, N, 2) the
    frame delivered, NaN where none; ``visible`` (T+1,) every marker in view."""

    plan: EpisodePlan
    time: FloatArray
    dt: FloatArray
    position: FloatArray
    velocity: FloatArray
    rotation: FloatArray
    images: FloatArray
    visible: BoolArray


@dataclass(eq=False)
class RecordedEpisode(EpisodeTruth):
    """One episode's target side, indexed by step (0 is reset, k the end of step k).

    The fields of `EpisodeTruth`, then what the estimator and the env derive from them:
    ``estimate_position``,
    ``estimate_velocity`` (T+1, 3), NaN where not ``estimate_valid``; ``estimate_covariance``
    (T+1, 6, 6), the EKF's covariance P of (position, velocity), NaN where it has none;
    ``estimator_status`` (T+1,)
    index into `capture_bench.sensing.estimator.STATUSES`; ``reachable`` (T+1,);
    ``position_error``, ``velocity_error``, ``nees`` (T+1,). ``bound`` is the episode's physical
    limit, None until asked for (the single env reads it from the plan, which carries it since
    it was drawn, at the end of an episode or when the oracle asks).
    ``continuation`` is None when every row holds the estimator's output; a recording whose EKF
    was run for its first rows only (`record_episodes` with ``estimated_steps``) says
    there where its estimates stop and the filter to continue from.
    """

    estimate_position: FloatArray
    estimate_velocity: FloatArray
    estimate_valid: BoolArray
    estimate_covariance: FloatArray
    estimator_status: NDArray[np.int8]
    reachable: BoolArray
    position_error: FloatArray
    velocity_error: FloatArray
    nees: FloatArray
    bound: PhysicalLimit | None
    continuation: EstimatorContinuation | None = None

    def rows(self, k: int, names: Sequence[str] | None = None) -> dict[str, NDArray]:
        """Step k's row of the tracks ``names`` (default `STEP_TRACKS`) as arrays of one
        row, (1, ...) views: the target side of one episode's step, as the step rule takes it."""
        return {name: getattr(self, name)[k : k + 1] for name in names or STEP_TRACKS}


@dataclass(eq=False)
class EstimatorContinuation:
    """Where a recording's estimates stop short of its time limit, and how to go on: rows 0 ..
    ``step`` - 1 of the estimate tracks hold the EKF's output (later rows hold no estimate, and
    their errors are NaN), and ``filter`` is the EKF's state after row ``step`` - 1
    (`TargetEstimator.restore` continues it bit for bit, with the frames
    ``images[step:]`` and periods ``dt[step:]``)."""

    step: int
    filter: FilterRows


#: The per-step quantities of a `RecordedEpisode` that a step reads, (T+1, ...) each.
STEP_TRACKS = (
    "time",
    "dt",
    "position",
    "velocity",
    "estimate_position",
    "estimate_velocity",
    "estimate_valid",
    "estimator_status",
    "visible",
    "reachable",
    "position_error",
    "velocity_error",
    "nees",
)


# position, velocity (T+1, 3), covariance (T+1, 6, 6) (NaN where none), valid, status (T+1,)
_Estimates = tuple[FloatArray, FloatArray, FloatArray, BoolArray, NDArray[np.int8]]


def record_episodes(
    scenario: Scenario,
    camera: Camera,
    features: FloatArray,
    description: TaskDescription,
    rngs: Sequence[np.random.Generator],
    estimated_steps: int | None = None,
) -> list[RecordedEpisode]:
    """The next episode of each generator, recorded to its time limit.

    Args:
        scenario: the scenario (the estimator's source and settings come from it).
        camera: the sensor (each episode captured from its start, `Camera.capture_sequence`).
        features: feature points, target frame, m, (N, 3).
        description: the task (arm and capture tolerance) for the bound.
        rngs: one generator per episode; each advances exactly as ``CaptureEnv`` with
            ``reuse_target_side`` advances it in ``reset``.
        estimated_steps: with the EKF source, run the EKF for the first ``estimated_steps``
            rows only (>= 1; the cold photogrammetry of the first frames is there) and give each
            episode its `EstimatorContinuation`, for a consumer that runs the rest of the
            filter only as far as the episode is played (``CaptureVectorEnv``). None: every
            row. The other sources always estimate every row.
    """
    if estimated_steps is not None and estimated_steps < 1:
        raise ValueError(f"estimated_steps must be None or >= 1, got {estimated_steps}")
    plans = draw_plans(scenario, camera.model, features, rngs)
    truths = [
        record_truth(plan, camera, features, rng) for plan, rng in zip(plans, rngs, strict=True)
    ]
    estimates, continuations = _estimate(scenario, camera, features, truths, estimated_steps)
    bounds = episode_bounds([t.plan for t in truths], description)
    return [
        _finish(truth, estimate, bound, continuation)
        for truth, estimate, bound, continuation in zip(
            truths, estimates, bounds, continuations, strict=True
        )
    ]


def record_truth(
    plan: EpisodePlan, camera: Camera, features: FloatArray, rng: np.random.Generator
) -> EpisodeTruth:
    """True states at every step time, and the frames (none with the truth source, whose env
    never calls the camera), over every step at once: bit for bit what the single env's
    step-by-step target side computes and draws (the trajectory's
    `states`,
    `Camera.capture_sequence`)."""
    time, dt = plan.step_times()
    truth_source = plan.scenario.estimator.source == "truth"
    position, velocity, rotation, points = plan.trajectory.states(
        time, None if truth_source else features
    )
    if points is None:
        images = np.full((time.size, features.shape[0], 2), np.nan)
        visible = np.ones(time.size, dtype=bool)
    else:
        images, visible = camera.capture_sequence(points, rng)
    return EpisodeTruth(plan, time, dt, position, velocity, rotation, images, visible)


def _estimate(
    scenario: Scenario,
    camera: Camera,
    features: FloatArray,
    truths: Sequence[EpisodeTruth],
    estimated_steps: int | None,
) -> tuple[list[_Estimates], list[EstimatorContinuation | None]]:
    """One estimator over all episodes together, a row each, step by step (episodes of
    different lengths stop taking part after their last step), through their last row or, with
    the EKF source, only the first ``estimated_steps`` rows (then with each episode's
    continuation where it has more)."""
    n = len(truths)
    source = scenario.estimator.source
    estimator = TargetEstimator(
        n, camera.model, features, source=source, **scenario.estimator_settings()
    )
    lengths = np.array([t.time.size for t in truths])
    n_steps = int(lengths.max())
    images = np.full((n_steps, n, features.shape[0], 2), np.nan)
    dt = np.full((n_steps, n), scenario.control.period)
    for i, t in enumerate(truths):
        images[: t.time.size, i] = t.images
        dt[: t.time.size, i] = t.dt
    true_states = None  # what the truth source reports, (T, n, 3) each
    if source == "truth":
        true_states = np.zeros((2, n_steps, n, 3))
        for i, t in enumerate(truths):
            true_states[:, : t.time.size, i] = t.position, t.velocity
    position = np.full((n, n_steps, 3), np.nan)
    velocity = np.full((n, n_steps, 3), np.nan)
    covariance = np.full((n, n_steps, 6, 6), np.nan)
    valid = np.zeros((n, n_steps), dtype=bool)
    status = np.zeros((n, n_steps), dtype=np.int8)
    stop = n_steps
    if estimated_steps is not None and source == "ekf":
        stop = min(estimated_steps, n_steps)
    for k in range(stop):
        truth = None if true_states is None else (true_states[0, k], true_states[1, k])
        out = estimator.update(images[k], dt[k], lengths > k, truth)
        position[:, k], velocity[:, k] = out.position, out.velocity
        covariance[:, k] = out.covariance
        valid[:, k], status[:, k] = out.valid, out.status
    continuations: list[EstimatorContinuation | None] = [None] * n
    if stop < n_steps:
        for i in np.flatnonzero(lengths > stop).tolist():
            continuations[i] = EstimatorContinuation(stop, estimator.snapshot([i]))
    estimates = [
        (position[i, :m], velocity[i, :m], covariance[i, :m], valid[i, :m], status[i, :m])
        for i, m in enumerate(lengths.tolist())
    ]
    return estimates, continuations


def _finish(
    truth: EpisodeTruth,
    estimates: _Estimates,
    bound: PhysicalLimit,
    continuation: EstimatorContinuation | None = None,
) -> RecordedEpisode:
    """Errors, NEES and reachability of every step, as ``CaptureEnv`` derives them."""
    position, velocity, covariance, valid, status = estimates
    position_error, velocity_error, nees = estimate_errors(
        position, velocity, covariance, valid, truth.position, truth.velocity
    )
    return RecordedEpisode(
        **vars(truth),
        estimate_position=position,
        estimate_velocity=velocity,
        estimate_valid=valid,
        estimate_covariance=covariance,
        estimator_status=status,
        reachable=kinematics.reachable(truth.position),
        position_error=position_error,
        velocity_error=velocity_error,
        nees=nees,
        bound=bound,
        continuation=continuation,
    )


def estimate_errors(
    position: FloatArray,
    velocity: FloatArray,
    covariance: FloatArray,
    valid: BoolArray,
    true_position: FloatArray,
    true_velocity: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(|X^_T - X_T|, |Xdot^_T - Xdot_T|, NEES)`` of T estimates, (T,) each, NaN where the
    estimate is not valid (the NEES also where it has no covariance, or P is not positive
    definite). A row's numbers do not depend on the other rows.

    Args:
        position, velocity: estimates, global, m and m/s, (T, 3).
        covariance: (T, 6, 6) of (position, velocity), NaN where none.
        valid: (T,) which estimates hold values.
        true_position, true_velocity: X_T and its rate, (T, 3).
    """
    error = np.concatenate((position - true_position, velocity - true_velocity), axis=1)
    norms = np.sqrt(np.add.reduce((error * error).reshape(-1, 2, 3), axis=2))  # (T, 2)
    has_nees = valid & np.isfinite(covariance.sum(axis=(1, 2)))
    if has_nees.all():
        try:  # e^T P^-1 e through one batched Cholesky factorisation
            return norms[:, 0], norms[:, 1], _nees(covariance, error)
        except np.linalg.LinAlgError:
            pass
    norms[~valid] = np.nan
    nees = np.full(valid.size, np.nan)
    rows = np.flatnonzero(has_nees)
    try:
        nees[rows] = _nees(covariance[rows], error[rows])
    except np.linalg.LinAlgError:
        # Some P not positive definite: NaN there, the same arithmetic row by row elsewhere.
        for k in rows.tolist():
            try:
                nees[k] = _nees(covariance[k : k + 1], error[k : k + 1])[0]
            except np.linalg.LinAlgError:
                pass
    return norms[:, 0], norms[:, 1], nees


def _nees(covariance: FloatArray, error: FloatArray) -> FloatArray:
    """``e^T P^-1 e`` of m rows, (m, 6, 6) and (m, 6): ``|L^-1 e|^2`` with ``P = L L^T``;
    ``LinAlgError`` if some P is not positive definite."""
    chol = np.linalg.cholesky(covariance)
    w = np.linalg.solve(chol, error[:, :, None])[:, :, 0]
    return np.einsum("ij,ij->i", w, w)
