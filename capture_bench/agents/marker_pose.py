"""A pixel policy's front end that reads the target's pose from the wide image, and the agent
made of it and a policy network (``front_end: marker_pose``, docs/pixels.md).

Each step, for each row (episode) of a batch of pixel observations:

1. **Markers.** The newest frame's four markers, read by hand (`HandReader`: no parameters, the
   markers' colours), and which of them show (`shown_markers`: at least `SHOWN` of the frame's
   largest weight; a marker the gripper or the block hides in part is pulled off its centre).
2. **Pose.** Where three or four show, eqs. 1-2 are solved for the target's pose from those
   markers alone (`capture_bench.sensing.photogrammetry.solve_poses`, the estimator's own solve)
   with the camera's calibration and the target's marker layout (`MarkerCalibration`: the
   scenario's published camera and feature points, as the estimator has them), warm-started
   from the row's last pose: three points have up to four poses, and the last one picks the
   branch. A row's first solve, and one whose warm start does not converge, use the
   multi-start. Fewer than three markers: the last pose stands.
3. **Features** of a step (`STEP_WIDTH` = 12):

   =====  ===================================================================================
   index  quantity
   =====  ===================================================================================
   0-2    the capture point (the last solved pose's origin) less X_E, global, dm (0 before any)
   3      1 where this step's pose was solved, else 0
   4      the share of the four markers that show
   5-11   the arm's state (the pixel observation's ``state``: Theta / pi, X_E / 1 m, dt / t_s)
   =====  ===================================================================================

   The policy network reads the last ``stack`` steps' features, oldest first
   (`front_end_space`); a row's first step fills all of them.

The pose is state carried from step to step, so the front end is not a function of one
observation: `MarkerPoseTracker` keeps it per row, `restart` clears a row at its episode's start.
`MarkerPoseAgent` is the agent evaluation runs (one episode at a time); training steps the same
tracker inside `capture_bench.training.common.front_end_vec_env.FrontEndVecEnv`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from capture_bench.sensing.camera import CameraModel
from capture_bench.sensing.photogrammetry import solve_poses
from capture_bench.sensing.pixels import pixel_to_image_plane
from capture_bench.sensing.workspace_image import sensor_pixels
from capture_bench.sim.markers import MARKER_COLOURS
from capture_bench.task.observation import OBSERVATION_BOUND, POSITION_SCALE, STATE_SIZE

#: The front ends a pixel policy may declare (``front_end`` in train.py and the model metadata).
FRONT_ENDS = ("marker_pose",)
POSE_WIDTH = 5  # features of the pose a step: the capture point less X_E, solved, shown share
STEP_WIDTH = POSE_WIDTH + STATE_SIZE
DECIMETRES = 10.0  # the capture point's offset from X_E, metres -> the features' units
DEFAULT_STACK = 3
MARKERS = len(MARKER_COLOURS)


@dataclass(frozen=True)
class MarkerCalibration:
    """What the front end knows of the camera and the target, as the estimator does: the
    camera's calibrated model, the target's feature points (marker centres, target frame, m,
    (4, 3)) and the wide image's size (width, height) whose pixels it reads."""

    model: CameraModel
    features: NDArray[np.float64]
    size: tuple[int, int]

    @classmethod
    def of_scenario(cls, scenario: Any, size: tuple[int, int]) -> MarkerCalibration:
        """The calibration of a scenario (name or `Scenario`) for images of ``size``."""
        from capture_bench.engine.task import scenario_camera
        from capture_bench.task.scenarios import Scenario, load_scenario

        found = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        camera, features = scenario_camera(found)
        return cls(camera.model, np.asarray(features, dtype=float), tuple(size))

    def image_plane(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Wide-image pixels (..., 2) -> eq. 2's image plane, metres (..., 2)."""
        p = np.asarray(pixels, dtype=float)
        sensor = sensor_pixels(self.model, self.size, p).reshape(-1, 2)
        return pixel_to_image_plane(sensor, self.model).reshape(p.shape)


def front_end_space(stack: int) -> spaces.Box:
    """The observation of the policy network behind the front end: ``stack`` steps' features."""
    return spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, (stack * STEP_WIDTH,), np.float32)


def read_markers(images: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The newest frame of pixel images (N, 3 k, H, W) uint8 -> its markers, wide-image pixels
    (N, 4, 2), and which show (N, 4) (module docstring, 1)."""
    import torch

    from capture_bench.agents.marker_reader import HandReader, shown_markers

    with torch.no_grad():
        frames = torch.as_tensor(np.ascontiguousarray(images[:, -3:])) / 255.0
        pixels, mass, _ = HandReader()(frames)
    return pixels.numpy().astype(float), shown_markers(mass.numpy())


class MarkerPoseTracker:
    """The front end (module docstring) for ``n`` rows.

    Args:
        calibration: the camera and the target's markers.
        n: rows.
        stack: steps the features hold.
        warm: False: every pose solved by the multi-start alone and none carried (the ablation).
    """

    def __init__(self, calibration: MarkerCalibration, n: int, stack: int = DEFAULT_STACK,
                 warm: bool = True) -> None:  # fmt: skip
        if stack < 1:
            raise ValueError(f"the front end's stack must be at least 1 step, got {stack}")
        self.calibration, self.n, self.stack, self.warm = calibration, n, stack, warm
        self.last = np.full((n, 6), np.nan)  # each row's last pose solved, camera frame
        self.history = np.zeros((n, stack, STEP_WIDTH), dtype=np.float32)
        self.fresh = np.ones(n, dtype=bool)  # rows whose next step is their episode's first

    def restart(self, rows: ArrayLike | None = None) -> None:
        """Rows ``rows`` (all: None) start an episode: no pose, the next step fills the stack."""
        index = slice(None) if rows is None else np.asarray(rows, dtype=np.intp)
        self.last[index] = np.nan
        self.fresh[index] = True

    def __call__(self, observations: dict[str, NDArray], rows: ArrayLike | None = None) -> Any:
        """Pixel observations of ``rows`` (all: None; ``image`` (M, 3 k, H, W) uint8, ``state``
        (M, 7)) -> the policy's observations (M, ``stack`` x `STEP_WIDTH`), float32."""
        index = np.arange(self.n) if rows is None else np.asarray(rows, dtype=np.intp)
        state = np.asarray(observations["state"], dtype=np.float32).reshape(len(index), -1)
        pixels, shown = read_markers(np.asarray(observations["image"]))
        step = np.zeros((len(index), STEP_WIDTH), dtype=np.float32)
        step[:, :POSE_WIDTH] = self.pose(pixels, shown, state[:, 3:6] * POSITION_SCALE, index)
        step[:, POSE_WIDTH:] = state
        fresh = self.fresh[index]
        history = self.history[index]
        history[~fresh, :-1] = history[~fresh, 1:]
        history[~fresh, -1] = step[~fresh]
        history[fresh] = step[fresh][:, None]
        self.history[index], self.fresh[index] = history, False
        return np.clip(history.reshape(len(index), -1), -OBSERVATION_BOUND, OBSERVATION_BOUND)

    def pose(self, pixels: ArrayLike, shown: ArrayLike, x_e: ArrayLike,
             rows: ArrayLike | None = None) -> NDArray[np.float32]:  # fmt: skip
        """Module docstring, 2-3: the pose features (M, `POSE_WIDTH`) of rows ``rows`` (all:
        None) from their markers, wide-image pixels (M, 4, 2), which show (M, 4) and X_E
        (M, 3), m; each row's pose kept for its next step."""
        index = np.arange(self.n) if rows is None else np.asarray(rows, dtype=np.intp)
        shown = np.asarray(shown, dtype=bool)
        x_e = np.asarray(x_e, dtype=float)
        cal = self.calibration
        plane = cal.image_plane(pixels)
        solved = np.zeros(len(index), dtype=bool)
        for pattern in {tuple(row) for row in shown if row.sum() >= 3}:
            at = np.flatnonzero(np.all(shown == pattern, axis=1))
            used = np.flatnonzero(pattern)
            guesses = self.last[index[at]] if self.warm else None
            found = solve_poses(plane[at][:, used], cal.features[used], cal.model.focal_length,
                                guesses)  # fmt: skip
            for k, solution in zip(at, found, strict=True):
                if solution.converged:
                    self.last[index[k]], solved[k] = solution.pose, True
        if not self.warm:
            self.last[index[~solved]] = np.nan
        out = np.zeros((len(index), POSE_WIDTH), dtype=np.float32)
        last = self.last[index]
        have = ~np.isnan(last[:, 0])
        if have.any():
            out[have, :3] = (cal.model.to_global(last[have, :3]) - x_e[have]) * DECIMETRES
        out[:, 3] = solved
        out[:, 4] = shown.sum(axis=1) / MARKERS
        return out


class MarkerPoseAgent:
    """A policy network behind the `MarkerPoseTracker` front end, as an agent of one episode at
    a time (`capture_bench.agents.protocol.Agent`): ``predict`` takes the pixel observation
    (a dict, one row or a batch of rows of one episode each), ``reset`` starts its episode(s).

    Args:
        learned: the network's agent (`capture_bench.agents.sb3_policy.SB3Policy`, or an SB3
            model: anything with ``predict`` on `front_end_space` observations).
        calibration: the camera and the target's markers.
        stack: the steps the network reads.
        name: label for reports.
    """

    privileged = False

    def __init__(self, learned: Any, calibration: MarkerCalibration, stack: int,
                 name: str = "marker_pose") -> None:  # fmt: skip
        self.learned, self.calibration, self.stack, self.name = learned, calibration, stack, name
        self.tracker: MarkerPoseTracker | None = None

    def predict(
        self,
        observation: dict[str, NDArray],
        state: Any = None,
        episode_start: NDArray | None = None,
        deterministic: bool = True,
    ) -> tuple[NDArray[np.float32], Any]:
        """The action of each row (a batch) or of the one observation, ``(action, state)``."""
        single = np.asarray(observation["image"]).ndim == 3
        obs = {k: np.asarray(v)[None] if single else np.asarray(v) for k, v in observation.items()}
        n = len(obs["image"])
        if self.tracker is None or self.tracker.n != n:
            self.tracker = MarkerPoseTracker(self.calibration, n, self.stack)
        if episode_start is not None:
            self.tracker.restart(np.flatnonzero(np.atleast_1d(episode_start)))
        action, _ = self.learned.predict(self.tracker(obs), deterministic=deterministic)
        action = np.asarray(action, dtype=np.float32).reshape(n, -1)
        return (action[0] if single else action), state

    def reset(self) -> None:
        """Start of an episode (of every row)."""
        if self.tracker is not None:
            self.tracker.restart()
