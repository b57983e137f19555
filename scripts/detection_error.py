"""The rendered camera's detection error in real episodes: found marker centroids against eq. 2's
projection of the true marker centres at the frame's time.

    python scripts/detection_error.py --scenario paper_rendered
    python scripts/detection_error.py --scenario paper_rendered --set camera.psf_sigma=0 \\
        --set camera.image_noise=0 --set camera.exposure=0 --frames 400

Plays the paper's controller (``incremental_ik``) on the scenario's validation seeds (or its
training seeds, ``--seeds training``; never a published seed), the arm and the target as in any
episode, and at every frame compares each marker the detector found with the eq. 2 pixel of the
marker's true centre at the frame's time t (the end of the exposure: what the estimator
assumes), until ``--frames`` frames with a marker found. Prints the per-axis RMS (the
estimator's ``noise_px`` is per axis), the radial RMS and 95th percentile, the 95th percentile
of |error| per axis, in pixels, and the share of markers found where all four centres are on the
sensor.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.sensing.pixels import pixel_of
from capture_bench.task.scenarios import ConfigError, Scenario, load_scenario, with_settings

SEED_SETS = ("validation", "training")


#: A found centroid farther than this from eq. 2 is a gross error, not the detector's noise, px.
OUTLIER_PX = 1.0


@dataclass(frozen=True)
class DetectionError:
    """Detected minus eq. 2 of the markers found, pixels.

    Attributes:
        errors: one row ``[du, dv]`` per marker found, shape (M, 2).
        frames: frames with a marker found.
        looked: markers in frames whose four centres were on the sensor (found or not).
        found: of those, found.
    """

    errors: np.ndarray
    frames: int
    looked: int
    found: int

    @property
    def rms_axis(self) -> float:
        """RMS of the error per axis (over u and v together), pixels."""
        return float(np.sqrt(np.mean(self.errors**2)))

    @property
    def outliers(self) -> int:
        """Markers found more than ``OUTLIER_PX`` from eq. 2 (a blob the arm cut or joined)."""
        return int(np.count_nonzero(np.hypot(*self.errors.T) > OUTLIER_PX))

    @property
    def rms_axis_inliers(self) -> float:
        """RMS per axis of the markers found within ``OUTLIER_PX`` of eq. 2, pixels: the
        detector's noise, which the EKF's measurement noise models (its NIS test and the
        divergence rule deal with the rare gross error)."""
        inliers = self.errors[np.hypot(*self.errors.T) <= OUTLIER_PX]
        return float(np.sqrt(np.mean(inliers**2)))

    @property
    def rms_radial(self) -> float:
        """RMS of the error's length, pixels."""
        return float(np.sqrt(np.mean(np.sum(self.errors**2, axis=1))))

    @property
    def p95_radial(self) -> float:
        """95th percentile of the error's length, pixels."""
        return float(np.percentile(np.hypot(*self.errors.T), 95))

    @property
    def p95_axis(self) -> float:
        """95th percentile of |error| per axis (u and v together), pixels."""
        return float(np.percentile(np.abs(self.errors), 95))


def measure(scenario: Scenario, frames: int, seeds: str = "validation") -> DetectionError:
    """The detection error over the first ``frames`` frames with a marker found, episode after
    episode of ``incremental_ik`` on ``seeds`` (``validation`` or ``training``) seeds."""
    pool = scenario.validation_seeds if seeds == "validation" else scenario.training_seeds
    env = CaptureEnv(scenario)
    agent = make_agent("incremental_ik", env)
    rows: list[np.ndarray] = []
    counts = [0, 0, 0]  # frames, looked, found
    try:
        for seed in pool:
            _play(env, agent, int(seed), rows, counts, frames)
            if counts[0] >= frames:
                break
    finally:
        env.close()
    errors = np.concatenate(rows) if rows else np.zeros((0, 2))
    return DetectionError(errors, *counts)


def _play(
    env: CaptureEnv, agent: Any, seed: int, rows: list, counts: list[int], frames: int
) -> None:
    """One episode of ``agent``, each frame's errors added to ``rows`` (``counts``: frames,
    markers looked for, found) until ``frames`` frames had a marker found."""
    env.action_space.seed(seed)
    agent.reset()
    obs, _ = env.reset(seed=seed)
    state, done, start = None, False, np.ones(1, dtype=bool)
    while True:
        _frame(env, rows, counts)
        if done or counts[0] >= frames:
            return
        action, state = agent.predict(obs, state=state, episode_start=start, deterministic=True)
        start = np.zeros(1, dtype=bool)
        obs, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated


def _frame(env: CaptureEnv, rows: list, counts: list[int]) -> None:
    """The latest frame's errors (its markers found against eq. 2 of the episode's true camera
    at its time)."""
    side = env.engine.sides.sides[0]  # type: ignore[union-attr]
    found = side.camera_episode.last_detections
    if found is None:  # dropped
        return
    episode, k = side.episode, side.filled - 1
    t, trajectory = float(episode.time[k]), episode.plan.trajectory
    # The detections are in the episode's true camera's pinhole image, before its lens and
    # principal point error (`SceneEpisode.last_detections`): compare with that camera's eq. 2.
    lens = side.camera_episode.lens
    model = env.camera_model if lens is None else lens.model
    points = trajectory.position(t) + env.task.features @ np.asarray(trajectory.rotation(t)).T
    centres = model.to_camera(points)
    truth = pixel_of(centres, model)
    if model.visible(centres).all():
        counts[1] += len(truth)
        counts[2] += int(found.found.sum())
    if found.found.any():
        counts[0] += 1
        rows.append(found.pixels[found.found] - truth[found.found])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_rendered", help="a rendered scenario")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="a scenario key to change, e.g. camera.psf_sigma=0.5 (repeatable)",
    )
    parser.add_argument("--frames", type=int, default=1000, help="frames with a marker found")
    parser.add_argument("--seeds", choices=SEED_SETS, default="validation")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error(f"--frames {args.frames} is not valid; expected a whole number >= 1")
    try:
        scenario = with_settings(load_scenario(args.scenario), args.set)
    except ConfigError as exc:
        print(f"detection_error.py: {exc}", file=sys.stderr)
        return 2
    if scenario.camera.mode != "rendered":
        print(f"detection_error.py: {args.scenario} has no rendered camera", file=sys.stderr)
        return 2
    result = measure(scenario, args.frames, args.seeds)
    cam = scenario.camera
    print(
        f"{scenario.name}: psf_sigma {cam.psf_sigma:g} px, image_noise {cam.image_noise:g}, "
        f"exposure {cam.exposure:g} s; {result.frames} frames, {len(result.errors)} markers found "
        f"({result.found}/{result.looked} of the markers on the sensor)"
    )
    print(
        "| RMS per axis, px | p95 per axis, px | RMS radial, px | p95 radial, px "
        f"| beyond {OUTLIER_PX:g} px | RMS per axis within it, px |"
    )
    print("|---|---|---|---|---|---|")
    print(
        f"| {result.rms_axis:.3f} | {result.p95_axis:.3f} | {result.rms_radial:.3f} | "
        f"{result.p95_radial:.3f} | {result.outliers} | {result.rms_axis_inliers:.3f} |"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
