"""How precisely the pixel observation's wide image locates the target: an independent reading.

    python scripts/pixel_depth.py --scenario paper --supersample 1 3 11 --seeds 40

For the first ``--seeds`` training seeds of the scenario (never a validation or published seed),
the target at 0, 0.5 and 1 s of the episode's own trajectory and the arm at home, renders
``obs["image"]`` as the pixel env does (84 x 84, `CaptureTask.imager`) at each
``image_supersample`` m, finds the four markers, maps their centroids to sensor pixels, solves
eqs. 1-2 for the target's pose (`solve_poses`, the estimator's photogrammetry) and compares the
capture point with the truth, per axis of the camera frame: x and z across the view, y along the
line of sight (depth). A frame counts where all four markers are found.

Each marker's centroid is the mean pixel position weighted by saturation over the pixels within
`READ_RADIUS_PX` of the detector's blob whose hue lies within `READ_HUE_DEG` of the marker's
(`read_markers`): an area-sampled edge pixel, part marker and part grey block, is partly
saturated, so the weights keep the sub-pixel position that area sampling puts in the image; on a
point-sampled image every marker pixel weighs the same and it is the blob's centroid.

A learned policy that reads depth no better than this cannot place the end-effector along the
line of sight any better from one frame; the figures are in docs/pixels.md.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import cv2
import gymnasium as gym
import numpy as np

from capture_bench.engine.task import CaptureTask
from capture_bench.sensing.detector import MARKER_BANDS, detect_markers
from capture_bench.sensing.photogrammetry import solve_poses
from capture_bench.sensing.pixels import pixel_to_image_plane
from capture_bench.sensing.workspace_image import PixelOptions, sensor_pixels
from capture_bench.sim.kinematics import HOME
from capture_bench.task.episode import draw_plans
from capture_bench.task.scenarios import ConfigError, load_scenario

READ_RADIUS_PX = 3.0  # image pixels around the detector's centroid a marker's reading uses
READ_HUE_DEG = 30.0  # hue difference from the marker's colour a pixel may have, degrees
TIMES_S = (0.0, 0.5, 1.0)  # instants of each episode's trajectory that are imaged


def read_markers(image: np.ndarray) -> np.ndarray | None:
    """The four markers' centroids in an RGB image ``(H, W, 3)``, image pixels ``[x, y]`` (pixel
    centres at whole numbers), (4, 2), weighted by saturation (module docstring); None unless
    the detector finds all four."""
    found = detect_markers(np.ascontiguousarray(image), None, min_area=1, min_fill=0.0)
    if not found.found.all():
        return None
    hsv = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2HSV).astype(float)
    rows, cols = np.mgrid[0 : image.shape[0], 0 : image.shape[1]]
    centroids = found.pixels.copy()
    for i, band in enumerate(MARKER_BANDS):
        hue_gap = np.abs((hsv[..., 0] * 2.0 - band.hue_deg + 180.0) % 360.0 - 180.0)
        near = np.hypot(cols - centroids[i, 0], rows - centroids[i, 1]) <= READ_RADIUS_PX
        weight = (near & (hue_gap <= READ_HUE_DEG)) * hsv[..., 1]
        centroids[i] = (weight * cols).sum() / weight.sum(), (weight * rows).sum() / weight.sum()
    return centroids


@dataclass(frozen=True)
class DepthReading:
    """Read minus true capture point, camera frame, m: one row ``[x, y, z]`` per frame read
    (y along the line of sight), ``errors`` (M, 3); ``frames``: frames imaged."""

    errors: np.ndarray
    frames: int

    def summary(self) -> dict[str, float]:
        """Median |error| per axis and the 90th percentile of the depth's, mm."""
        e = np.abs(self.errors) * 1000.0
        return {
            "across_x_mm": float(np.median(e[:, 0])),
            "depth_mm": float(np.median(e[:, 1])),
            "across_z_mm": float(np.median(e[:, 2])),
            "depth_p90_mm": float(np.percentile(e[:, 1], 90)),
        }


def depth_reading(scenario_name: str, supersample: int, seeds: int) -> DepthReading:
    """`read_markers` and the pose solve on the wide image at ``image_supersample`` m =
    ``supersample``, for the scenario's first ``seeds`` training seeds at `TIMES_S`."""
    scenario = load_scenario(scenario_name)
    task = CaptureTask(scenario, observation_source="pixels", image_supersample=supersample)
    imager = task.imager()
    model, features = task.camera.model, task.features
    rngs = [gym.utils.seeding.np_random(seed)[0] for seed in scenario.training_seeds[:seeds]]
    errors, frames = [], 0
    try:
        for plan in draw_plans(scenario, model, features, rngs):
            position, _, rotation, _ = plan.trajectory.states(np.asarray(TIMES_S), None)
            for k in range(len(TIMES_S)):
                frames += 1
                image = imager.render(HOME, position[k], rotation[k]).transpose(1, 2, 0)
                centroids = read_markers(image)
                if centroids is None:
                    continue
                sensor = sensor_pixels(model, imager.size, centroids)
                plane = pixel_to_image_plane(sensor, model)
                (solution,) = solve_poses(plane[None], features, model.focal_length)
                errors.append(solution.pose[:3] - model.to_camera(position[k][None])[0])
    finally:
        imager.close()
    return DepthReading(np.reshape(errors, (-1, 3)), frames)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="paper")
    parser.add_argument(
        "--supersample", type=int, nargs="+", default=[1, 3, 11],
        help="image_supersample values m to read, 1 (point sampling) to 11",
    )  # fmt: skip
    parser.add_argument("--seeds", type=int, default=40, help="training seeds, from the first")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        print("error: --seeds must be at least 1", file=sys.stderr)
        return 2
    try:
        load_scenario(args.scenario)
        for m in args.supersample:
            PixelOptions.check(image_supersample=m)
    except (ConfigError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print("| image_supersample | frames read | median error across x, mm | median depth error, "
          "mm | 90th percentile of depth error, mm | median error across z, mm |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for m in args.supersample:
        reading = depth_reading(args.scenario, m, args.seeds)
        if not len(reading.errors):
            print(f"| {m} | 0 of {reading.frames} | | | | |")
            continue
        got = reading.summary()
        cells = [f"{len(reading.errors)} of {reading.frames}"]
        cells += [f"{got[key]:.1f}" for key in ("across_x_mm", "depth_mm", "depth_p90_mm")]
        print(f"| {m} | {' | '.join(cells)} | {got['across_z_mm']:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
