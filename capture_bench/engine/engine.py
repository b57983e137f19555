"""N capture episodes stepped as rows: `EpisodeEngine`.

An engine holds what N episodes carry from step to step (`ArmState`, the target side's
`Tracks`, each row's recording, step index and bound) and applies one step to any subset of
rows: the arm's side (`ArmSide`: rate and joint limits, forward kinematics, collisions), the
target's side (`TargetSides`: recorded ahead or computed as the step comes), then the task's
rules (`capture_bench.task.step_rule.StepRule`: capture along the arc, eq. 20; failures;
reward; ``info``'s values). It knows no seeds policy, no autoreset and no gymnasium format: the
environments (`capture_bench.envs`) are those around it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from capture_bench.engine.arm import ArmSide
from capture_bench.engine.sides import ArmMotion, EpisodeDraw, Rows, Steps, TargetSides
from capture_bench.engine.task import CaptureTask, Observation
from capture_bench.engine.tracks import Tracks
from capture_bench.sensing.workspace_image import WorkspaceImager
from capture_bench.sim.target_motion import TargetTrajectory
from capture_bench.task.observation import encode_observation
from capture_bench.task.recording import RecordedEpisode
from capture_bench.task.step_rule import BEFORE_TRACKS, ArmState, StepOutcome

FloatArray = NDArray[np.float64]
_OBSERVED = ("estimate_valid", "estimate_position", "estimate_velocity", "dt")


class FrameStack:
    """The last k frames of each image view of N rows, oldest first, stacked along the channels
    (or of any per-row values, (N, ...) a step, kept in their dtype: stacked along their first
    axis after the row's).

    A row's stack takes a frame when its step has moved since the last (a row the caller did not
    step keeps its stack), and is filled with k copies of its first frame when its episode
    restarts (`restart`).
    """

    def __init__(self, n: int, k: int) -> None:
        self.n, self.k = n, k
        self.frames: dict[str, NDArray] = {}  # view -> (N, k, 3, H, W)
        self.step = np.full(n, -1, dtype=np.int64)  # each row's step of its newest frame
        self.fresh = np.ones(n, dtype=bool)  # rows whose episode restarted since

    def restart(self, rows: NDArray[np.intp]) -> None:
        """Rows ``rows`` start an episode: their next frame fills their stacks."""
        self.fresh[rows] = True

    def push(self, views: dict[str, NDArray], steps: NDArray[np.int64]) -> dict[str, NDArray]:
        """Take each row's frame of every view in ``views`` ((N, 3, H, W) each) where its step
        (``steps``, (N,)) moved or its episode restarted; the stacks, (N, 3 k, H, W) each (values
        (N, d, ...): (N, k d, ...))."""
        moved = self.fresh | (steps != self.step)
        refill, roll = self.fresh.copy(), moved & ~self.fresh
        stacked = {}
        for key, frame in views.items():
            stack = self.frames.get(key)
            if stack is None:
                stack = np.empty((self.n, self.k, *frame.shape[1:]), frame.dtype)
                self.frames[key] = stack
            stack[roll, :-1] = stack[roll, 1:]
            stack[roll, -1] = frame[roll]
            stack[refill] = frame[refill][:, None]
            stacked[key] = stack.reshape(self.n, -1, *frame.shape[2:]).copy()
        self.step[moved] = steps[moved]
        self.fresh[:] = False
        return stacked


class EpisodeEngine:
    """N episodes of one task, stepped as rows.

    Args:
        task: the task (`CaptureTask`).
        n: the number of rows.
        sides: the target sides of the rows (`capture_bench.engine.sides.target_sides`).
        arm: the arm's side (`ArmSide`).

    Attributes:
        state: what the step rule carries per row (`ArmState`).
        tracks: the target side of every row, step by step (`Tracks`).
        steps: steps since each row's start, (N,).
        episodes: each row's recording (None before its first start; its ``bound`` set where
            the target sides bound their episodes, the recorded and the rendered).

    A one-row engine (the single env) may step and observe its row as ``slice(None)``: the
    same rule on views instead of index arrays.
    """

    def __init__(self, task: CaptureTask, n: int, sides: TargetSides, arm: ArmSide) -> None:
        self.task, self.rule, self.n = task, task.rule, n
        self.sides, self.arm = sides, arm
        self.state = ArmState.empty(n)
        self.tracks = Tracks(n, task.steps)
        self.steps = np.zeros(n, dtype=np.int64)
        self.episodes: list[RecordedEpisode | None] = [None] * n
        # observation_source "pixels": one renderer draws every row's image in turn
        self._imager: WorkspaceImager | None = task.imager() if task.pixels else None
        k = task.pixel_options.frame_stack
        self._stack: FrameStack | None = FrameStack(n, k) if task.pixels and k > 1 else None

    def prepare(self, draws: Sequence[EpisodeDraw]) -> list[RecordedEpisode | EpisodeDraw]:
        """What `begin` takes for the next episode of each draw (`TargetSides.prepare`)."""
        return self.sides.prepare(draws)

    def begin(
        self, rows: NDArray[np.intp], prepared: Sequence[RecordedEpisode | EpisodeDraw]
    ) -> dict[str, NDArray]:
        """Start the episode ``prepared[j]`` in row ``rows[j]``, the arm at home; returns the
        rows' reset ``info`` values (`StepRule.start`)."""
        episodes = self.sides.begin(rows.tolist(), prepared, self.tracks)
        for i, episode in zip(rows.tolist(), episodes, strict=True):
            self.episodes[i] = episode
        self.steps[rows] = 0
        if self._stack is not None:
            self._stack.restart(rows)
        return self.rule.start(self.state, rows, self.tracks["position"][rows, 0])

    def step(self, idx: Rows, actions: FloatArray) -> StepOutcome:
        """One step of the rows ``idx`` with their ``actions`` (M, 3), checked, in [-1, 1]
        after clipping: the arm's side, the target's side, then the step rule, in place."""
        tracks = self.tracks
        k: Steps
        if isinstance(idx, slice):  # the one row of a one-row engine
            k = int(self.steps[0]) + 1
            self.steps[0] = k
        else:
            k = self.steps[idx] + 1
            self.steps[idx] = k
        theta0 = self.state.theta[idx]
        theta, pose, clipped, saturated = self.arm.move(
            theta0, self.task.increments(actions), tracks["dt"][idx, k]
        )
        self.sides.advance(idx, k, ArmMotion(theta0, theta), tracks)
        before = {name: tracks[name][idx, k - 1] for name in BEFORE_TRACKS}
        after = {name: track[idx, k] for name, track in tracks.items()}

        def collides(ask: NDArray[np.bool_]) -> NDArray[np.bool_]:
            return self.arm.collides(theta, ask)

        def trajectory(j: int) -> TargetTrajectory:
            episode = self.episodes[j if isinstance(idx, slice) else idx[j]]
            assert episode is not None
            return episode.plan.trajectory

        return self.rule.step(
            self.state, idx, before, after, theta, pose, clipped, saturated, collides, trajectory
        )

    def observe(self) -> Observation:
        """Every row's observation at its current step (the last real period: that of the step
        just taken, t_s at the start); with pixels, the images of the arms and of the true
        targets (with a frame stack, each row's last k), and the states."""
        if self._imager is None:
            return self.observe_estimate()
        rows, k = self._now()
        rotation = self._rotations()
        position, dt = self.tracks["position"][rows, k], self.tracks["dt"][rows, k]
        views = self.task.pixel_observation(
            self._imager, self.state, slice(None), position, rotation, dt
        )
        if self._stack is None:
            return views
        images = {key: value for key, value in views.items() if key != "state"}
        return {**self._stack.push(images, self.steps), "state": views["state"]}

    def observe_estimate(self) -> NDArray[np.float32]:
        """Every row's estimate-fed observation at its current step, (N, 16): what an env
        observing the scenario's estimator gives; with pixels, the estimate the agent does not
        see (the estimator runs for ``info``), which an analytic teacher reads."""
        rows, k = self._now()
        now = {name: self.tracks[name][rows, k] for name in _OBSERVED}
        return self.rule.observe(self.state, slice(None), now)

    def observe_truth(self) -> NDArray[np.float32]:
        """Every row's observation at its current step with the target's true position and
        velocity in place of the estimate, (N, 16), `encode_observation`'s layout (privileged:
        an asymmetric critic's input)."""
        rows, k = self._now()
        tracks = self.tracks
        return encode_observation(
            tracks["position"][rows, k],
            tracks["velocity"][rows, k],
            self.state.x_e,
            self.state.theta,
            tracks["dt"][rows, k],
            self.task.description.control_period,
        )

    def true_features(self) -> NDArray[np.float64]:
        """Every row's target feature points (the marker centres) at its current step, global,
        m, (N, F, 3): X_T + R_gt f for the task's features f (privileged: the truth behind the
        image, for supervising what a pixel network reads)."""
        rows, k = self._now()
        position = np.reshape(self.tracks["position"][rows, k], (-1, 3))
        features = np.einsum("nij,fj->nfi", self._rotations(), self.task.features)
        return position[:, None, :] + features

    def true_image_points(self) -> NDArray[np.float64]:
        """Where every row's target feature points lie in the wide image, [column, row] in its
        pixels, (N, F, 2) (privileged: what a pixel network's keypoints are fitted to;
        `WorkspaceImager.image_points`). Pixel tasks only."""
        if self._imager is None:
            raise ValueError("true_image_points: the task renders no image (pixels only)")
        return self._imager.image_points(self.true_features())

    def _rotations(self) -> NDArray[np.float64]:
        """Every row's target attitude R_gt at its current step, (N, 3, 3), from its recording."""
        return np.stack(
            [
                episode.rotation[j]  # type: ignore[union-attr]
                for episode, j in zip(self.episodes, self.steps.tolist(), strict=True)
            ]
        )

    def _now(self) -> tuple[Rows, Steps]:
        """Every row and its current step (for one row, a slice and a step: views)."""
        if self.n == 1:
            return slice(None), int(self.steps[0])
        return np.arange(self.n), self.steps

    def time(self, i: int) -> float:
        """Simulated time since row ``i``'s start, s."""
        return float(self.tracks["time"][i, self.steps[i]])

    def close(self) -> None:
        """Release the worlds the engine holds (the arm's, the renderers'); safe twice."""
        self.arm.close()
        self.sides.close()
        if self._imager is not None:
            self._imager.close()
            self._imager = None
