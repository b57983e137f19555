"""What a clone of `dls` does when the markers it reads in the wide image go through the
estimator's photogrammetry before its MLP: the target's geometry given, not learned.

A probe beside `scripts/pixel_keypoint_probe.py` (docs/pixels.md, "The target's geometry"), whose
rows, readers and closed-loop play it shares:

1. **Data.** The keypoint probe's rows (`collect`: `dls` with DART noise on `paper`'s training
   seeds; validation rows from the validation seeds after the first ``--episodes``).
2. **Markers.** Each frame's four markers by ``--reader``: ``hand`` (`HandReader`, the markers'
   colours read by hand, no parameters) or ``oracle`` (the privileged points, exact, of the
   markers that show). A marker shows where its hand-read weight is at least half of the
   frame's largest (`shown_markers`): partly hidden, its centroid is pulled off.
3. **Pose** (`pose_reading`). Where three or four markers show, eqs. 1-2 are solved for the
   target's pose from those markers alone (`capture_bench.sensing.photogrammetry.solve_poses`,
   the estimator's own solve), warm-started from the sub-env's last pose, as the estimator's
   photogrammetry is (three points have up to four poses; the last one picks the branch;
   ``--cold``: every step's solved by the multi-start alone, none carried). The
   features of a step: the capture point (the target frame's origin) less X_E, in decimetres,
   from the last pose solved (0 before any), whether this step's was solved, and the share of
   markers that show. Fewer than three: the last pose stands.
4. **Head.** An MLP (256 x 2) on the features of the last ``--stack`` steps and the arm's state,
   standardised, fitted ``--epochs`` epochs (Adam, one-cycle, minibatches of 128) to the
   teacher's action and the relative vector.
5. **Report.** The relative vector's error (all validation rows and those within 50 mm of the
   target), the pose alone's error there, the share of steps solved, and the captures of the
   first ``--episodes`` validation seeds played closed-loop.

    python scripts/pixel_pose_probe.py --train-steps 64000 --stack 3
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
import pixel_keypoint_probe as keypoint_probe  # noqa: E402 (beside this script)

from capture_bench.agents.marker_pose import (  # noqa: E402
    DECIMETRES,
    MarkerCalibration,
    MarkerPoseTracker,
    read_markers,
)
from capture_bench.agents.marker_pose import POSE_WIDTH as WIDTH  # noqa: E402
from capture_bench.engine.engine import FrameStack  # noqa: E402
from capture_bench.sensing.workspace_image import IMAGE_SIZE  # noqa: E402
from capture_bench.task.scenarios import load_scenario  # noqa: E402

NUM_ENVS = keypoint_probe.NUM_ENVS
MARKERS = keypoint_probe.MARKERS


def pose_reading(scenario: str, warm: bool = True) -> MarkerPoseTracker:
    """`NUM_ENVS` sub-envs' front end (module docstring, 3): `MarkerPoseTracker.pose` on the
    markers read (``warm`` False: every pose solved cold, none carried)."""
    return MarkerPoseTracker(MarkerCalibration.of_scenario(scenario, IMAGE_SIZE), NUM_ENVS,
                             warm=warm)  # fmt: skip


def markers(views: np.ndarray, points: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Frames (N, 3, H, W) uint8 -> the markers (N, 4, 2), wide-image pixels, hand-read or, given
    the privileged ``points`` (N, >= 4, 2), those; and which show (N, 4) (module docstring, 2)."""
    pixels, shown = read_markers(views)
    found = pixels if points is None else np.asarray(points)[:, :MARKERS]
    return found.astype(float), shown


def pose_rows(rows: keypoint_probe.Rows, reading: MarkerPoseTracker, oracle: bool) -> np.ndarray:
    """Every row's features (N, `WIDTH`), the rows in `collect`'s order (step after step,
    `NUM_ENVS` rows a step), each sub-env's poses warm-started from its last."""
    n = len(rows.state)
    out = np.zeros((n, WIDTH), dtype=np.float32)
    reading.restart(np.arange(NUM_ENVS))
    for lo in range(0, n, NUM_ENVS):
        index = np.arange(lo, min(lo + NUM_ENVS, n))
        reading.restart(np.flatnonzero(rows.first[index]))
        found, shown = markers(rows.views["image"][index],
                               rows.points["image"][index] if oracle else None)  # fmt: skip
        pad = NUM_ENVS - len(index)  # a last, partial step
        if pad:
            found, shown = (
                np.pad(found, ((0, pad), (0, 0), (0, 0))),
                np.pad(shown, ((0, pad), (0, 0))),
            )
        x_e = np.pad(rows.state[index, 3:6].astype(float), ((0, pad), (0, 0)))
        out[index] = reading.pose(found, shown, x_e)[: len(index)]
    return out


class PoseHead(nn.Module):
    """The features of the last ``stack`` steps and the arm's state, standardised -> the action
    (3) and the relative vector (3, standardised)."""

    def __init__(self, stack: int, state: int = 7, hidden: int = 256) -> None:
        super().__init__()
        width = stack * (WIDTH + state)
        self.stack = stack
        self.net = nn.Sequential(nn.Linear(width, hidden), nn.ReLU(), nn.Linear(hidden, hidden),
                                 nn.ReLU(), nn.Linear(hidden, 6))  # fmt: skip
        for name in ("mean", "std"):
            self.register_buffer(name, torch.zeros(width) if name == "mean" else torch.ones(width))
        self.register_buffer("relative_mean", torch.zeros(3))
        self.register_buffer("relative_std", torch.ones(3))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.net((x - self.mean) / self.std)
        return out[:, :3], out[:, 3:]


def inputs(features: np.ndarray, rows: keypoint_probe.Rows, stack: int) -> torch.Tensor:
    """Each row's features and state, with those of its last ``stack`` steps, (N, S D)."""
    x = torch.as_tensor(np.concatenate((features, rows.state), axis=1))
    return keypoint_probe.stacked(x, rows.first, stack).flatten(1)


def fit(head: PoseHead, x: torch.Tensor, rows: keypoint_probe.Rows, epochs: int, lr: float,
        seed: int) -> None:  # fmt: skip
    """Module docstring, 4."""
    rng = np.random.default_rng(seed)
    head.mean.copy_(x.mean(0))
    head.std.copy_(x.std(0) + 1e-3)
    head.relative_mean.copy_(torch.as_tensor(rows.relative.mean(0)))
    head.relative_std.copy_(torch.as_tensor(rows.relative.std(0) + 1e-6))
    action = torch.as_tensor(rows.action)
    relative = (torch.as_tensor(rows.relative) - head.relative_mean) / head.relative_std
    params = list(head.parameters())
    keypoint_probe.fit_on_features(head, params, x, action, relative, epochs, lr, rng)


class PoseStudent:
    """The head acting on `NUM_ENVS` sub-envs (`keypoint_probe.play`'s student): each step's
    newest frame (and, an oracle's, the privileged points) -> its markers -> `pose_reading` ->
    the last steps' features -> actions in [-1, 1]."""

    def __init__(self, head: PoseHead, reading: MarkerPoseTracker, oracle: bool) -> None:
        self.head, self.reading, self.oracle = head, reading, oracle
        self.points = ["image"] if oracle else []
        self.recent = FrameStack(NUM_ENVS, head.stack)

    def restart(self, rows: np.ndarray) -> None:
        self.reading.restart(rows)
        self.recent.restart(rows)

    def __call__(self, obs: dict, found: dict | None, t: int) -> np.ndarray:
        pixels, shown = markers(obs["image"][:, -3:], found["image"] if self.oracle else None)
        f = self.reading.pose(pixels, shown, obs["state"][:, 3:6].astype(float))
        x = np.concatenate((f, obs["state"]), axis=1).astype(np.float32)
        x = self.recent.push({"x": x}, np.full(NUM_ENVS, t))["x"].reshape(NUM_ENVS, -1)
        with torch.no_grad():
            a, _ = self.head(torch.as_tensor(x))
        return np.clip(a.numpy(), -1, 1)


def probe(args: argparse.Namespace) -> dict[str, object]:
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)
    scenario = load_scenario(args.scenario)
    options = {"image_supersample": args.image_supersample}
    oracle = args.reader == "oracle"
    start = time.perf_counter()
    train = keypoint_probe.collect(args.scenario, options, args.train_steps,
                                   scenario.training_seeds)  # fmt: skip
    validation = keypoint_probe.collect(args.scenario, options, args.validation_steps,
                                        scenario.validation_seeds[args.episodes :])  # fmt: skip
    collected = time.perf_counter() - start
    reading = pose_reading(args.scenario, warm=not args.cold)
    f_train, f_val = pose_rows(train, reading, oracle), pose_rows(validation, reading, oracle)
    head = PoseHead(args.stack)
    fit(head, inputs(f_train, train, args.stack), train, args.epochs, args.lr, args.seed)
    with torch.no_grad():
        _, r = head(inputs(f_val, validation, args.stack))
    predicted = (r * head.relative_std + head.relative_mean).numpy()
    error = np.abs(predicted - validation.relative).astype(float) * 1e3  # mm
    alone = np.abs(f_val[:, :3] / DECIMETRES - validation.relative).astype(float) * 1e3
    near = np.linalg.norm(validation.relative, axis=1) < keypoint_probe.NEAR
    student = PoseStudent(head, reading, oracle)
    captured = keypoint_probe.play(None, args.scenario, options, args.episodes, student=student)
    near_report = {
        "near_median_mm": np.median(error[near], 0).round(1).tolist(),
        "near_p90_mm": np.percentile(error[near], 90, 0).round(1).tolist(),
        "near_pose_alone_median_mm": np.median(alone[near], 0).round(1).tolist(),
        "near_solved_share": round(float(f_val[near, 3].mean()), 3),
    } if near.any() else {}  # fmt: skip
    return {
        "options": options, "reader": args.reader, "stack": args.stack, "epochs": args.epochs,
        "warm_start": not args.cold,
        "train_rows": len(train.state), "rows": len(validation.state),
        "relative_median_mm": np.median(error, 0).round(1).tolist(),
        "relative_p90_mm": np.percentile(error, 90, 0).round(1).tolist(),
        "solved_share": round(float(f_val[:, 3].mean()), 3), "near_share": float(near.mean()),
        **near_report, "captured": captured, "episodes": args.episodes,
        "collect_s": round(collected, 1), "wall_clock_s": round(time.perf_counter() - start, 1),
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--image-supersample", type=int, default=3)
    parser.add_argument("--reader", choices=("hand", "oracle"), default="hand",
                        help="the markers read by hand, or the privileged points of those that "
                        "show")  # fmt: skip
    parser.add_argument(
        "--cold",
        action="store_true",
        help="solve every step's pose from scratch, none carried from the last",
    )
    parser.add_argument("--train-steps", type=int, default=64000)
    parser.add_argument("--validation-steps", type=int, default=8000)
    parser.add_argument("--stack", type=int, default=3, help="the head reads the last S steps")
    parser.add_argument("--epochs", type=int, default=32)
    parser.add_argument("--lr", type=float, default=2e-3)
    parser.add_argument("--episodes", type=int, default=48, help="validation seeds played")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="write the report here as JSON")
    args = parser.parse_args(argv)
    if min(args.train_steps, args.validation_steps, args.stack, args.epochs) < 1:
        print("pixel_pose_probe: --train-steps, --validation-steps, --stack and --epochs must "
              "be at least 1", file=sys.stderr)  # fmt: skip
        return 2
    return keypoint_probe.run_and_report("pixel_pose_probe", probe, args, argv)


if __name__ == "__main__":
    sys.exit(main())
