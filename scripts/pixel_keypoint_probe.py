"""How well a keypoint network reads the target from the pixel observation, and what its clone of
`dls` does with it.

A probe, not a training run of `train.py`: it measures whether an observation design gives a
pixel network what the envelope asks (the target's position relative to the end-effector to a
few millimetres, along the line of sight too) before anything is trained on it for hours.

1. **Data.** `dls` plays the pixel env's episodes on the scenario's training seeds, acting on the
   estimate-fed observation (its teacher's view); on every second sub-env its action is
   perturbed by Gaussian noise (DART, Laskey et al. 2017) so that the data set holds states off
   the teacher's path labelled with its action there. Each row: the views, the arm's state, the
   teacher's action, the true predicted relative vector X_T' - X_E (eq. 13) and, privileged,
   where the target's feature points and X_E lie in each view (`WorkspaceImager.view_points`).
   Validation rows come from the first validation seeds, episodes never trained on.
2. **Network.** Each view through a 3 x 3 convolution to 16 maps, a ReLU and a 1 x 1 convolution
   to `KEYPOINTS` maps, then a spatial softmax (`capture_bench.agents.features.SpatialSoftmax`):
   each map's expected position, its log-sum-exp (how much it found) and the log distances
   between keypoints (the markers' spacing, which is what tells depth). An MLP (256, 256) on
   those and the arm's state, standardised, gives the action and the relative vector.
3. **Fit.** Adam, one-cycle schedule, minibatches of 128: the action's squared error, the relative
   vector's (standardised) and, with privileged supervision, the squared pixel error of keypoint
   k against feature point k (then X_E) where that point lies inside the view.
4. **Report.** On the validation rows: each supervised keypoint's median pixel error, the relative
   vector's median and 90th-percentile error per axis (all rows, and the rows within 50 mm of
   the target), the action's error; then the network plays the first validation seeds of the
   scenario closed-loop and the captures are counted under the scenario's envelope.

``python scripts/pixel_keypoint_probe.py --ee-crop 75 --ee-crop-scale 3`` (docs/pixels.md,
"What a keypoint network reads").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from capture_bench.agents.features import SpatialSoftmax
from capture_bench.engine.task import CaptureTask, resolve_scenario
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.task.episode import describe_task
from capture_bench.task.observation import RELATIVE_SCALE, SLICES
from capture_bench.task.scenarios import ConfigError, load_scenario
from capture_bench.training.common.imitation import make_teacher

KEYPOINTS = 8  # maps per view; the first F + 1 are supervised (F feature points, then X_E)
HIDDEN = 16
NEAR = 0.05  # m: rows this close to the target are reported apart
NUM_ENVS = 16
DART_NOISE = 0.3  # std of the action noise on every second sub-env (actions in [-1, 1])
BATCH = 128


@dataclass
class Rows:
    """A data set: ``views`` name -> (N, 3, H, W) uint8; ``points`` name -> (N, F + 1, 2) view
    pixels; ``state`` (N, 7); ``action`` (N, 3), the teacher's; ``relative`` (N, 3), m."""

    views: dict[str, np.ndarray]
    points: dict[str, np.ndarray]
    state: np.ndarray
    action: np.ndarray
    relative: np.ndarray


class SeedList:
    """Episode seeds in a given order (an `EpisodeSeedSource`)."""

    def __init__(self, seeds: Sequence[int]) -> None:
        self._seeds = iter(seeds)

    def next(self) -> int:
        return next(self._seeds)


def make_env(scenario: str, options: dict[str, int], **kwargs: object) -> CaptureVectorEnv:
    return CaptureVectorEnv(NUM_ENVS, scenario, observation_source="pixels", **options, **kwargs)


def collect(scenario: str, options: dict[str, int], steps: int, seeds: Sequence[int]) -> Rows:
    """``steps`` rows of `dls` with DART noise (module docstring, 1) on episodes seeded from
    ``seeds`` in turn (one per sub-env reset)."""
    venv = make_env(scenario, options)
    venv.set_episode_seeds([SeedList(seeds[i::NUM_ENVS]) for i in range(NUM_ENVS)])
    teacher = make_teacher(["dls"], [describe_task(resolve_scenario(scenario, "pixels"))],
                           [NUM_ENVS])  # fmt: skip
    imager = CaptureTask(load_scenario(scenario), observation_source="pixels", **options).imager()
    rng = np.random.default_rng(seeds[0])
    noise = np.where(np.arange(NUM_ENVS) % 2 == 1, DART_NOISE, 0.0)[:, None]
    names = ["image", *(["ee_image"] if options.get("ee_crop") else [])]
    frames = {k: [] for k in names}
    points = {k: [] for k in names}
    state, action, relative = [], [], []
    obs, _ = venv.reset()
    try:
        for _ in range(-(-steps // NUM_ENVS)):
            label = teacher(venv.estimate_observation())
            truth = venv.true_observation()
            features = venv.true_features()
            for k in names:
                frames[k].append(obs[k][:, -3:])  # the newest frame
            for i in range(NUM_ENVS):
                x_e = obs["state"][i, 3:6].astype(float)
                found = imager.view_points(np.vstack([features[i], x_e]), x_e)
                for k in names:
                    points[k].append(found[k])
            state.append(obs["state"])
            action.append(label)
            relative.append(truth[:, SLICES["relative_position"]] * RELATIVE_SCALE)
            noisy = label + noise * rng.standard_normal(label.shape)
            obs, *_ = venv.step(np.clip(noisy, -1.0, 1.0).astype(np.float32))
    finally:
        imager.close()
        venv.close()
    n = len(state) * NUM_ENVS
    return Rows(
        {k: np.concatenate(v)[:steps] for k, v in frames.items()},
        {k: np.asarray(v, dtype=np.float32).reshape(n, -1, 2)[:steps] for k, v in points.items()},
        np.concatenate(state)[:steps],
        np.concatenate(action)[:steps].astype(np.float32),
        np.concatenate(relative)[:steps].astype(np.float32),
    )


def local_soft_argmax(maps: torch.Tensor, temperature: torch.Tensor, half: int) -> torch.Tensor:
    """Each map's (B, K, H, W) expected position under its softmax over the (2 half + 1)^2 pixels
    around its largest value (the window moved inside the map at the edges), [x, y] in pixels,
    (B, K, 2): the background beyond the window has no weight to pull it."""
    b, k, h, w = maps.shape
    peak = maps.flatten(2).argmax(-1)
    side = 2 * half + 1
    r0 = (peak // w).clamp(half, h - 1 - half) - half
    c0 = (peak % w).clamp(half, w - 1 - half) - half
    offsets = torch.arange(side, device=maps.device)
    rows = (r0[..., None] + offsets)[..., :, None].expand(b, k, side, side)
    cols = (c0[..., None] + offsets)[..., None, :].expand(b, k, side, side)
    flat = (rows * w + cols).reshape(b, k, -1)
    weights = torch.softmax(maps.flatten(2).gather(-1, flat) / temperature, dim=-1)
    x = (weights * cols.reshape(b, k, -1)).sum(-1)
    y = (weights * rows.reshape(b, k, -1)).sum(-1)
    return torch.stack((x, y), dim=-1).float()


class ViewKeypoints(nn.Module):
    """One view (B, 3, H, W) uint8 -> its keypoints in pixels, a list of (B, K, 2) (the whole
    view's spatial softmax, and with ``window`` > 0 the `local_soft_argmax` that the features
    read), and features (B, D)."""

    def __init__(self, size: int, window: int = 0) -> None:
        super().__init__()
        self.maps = nn.Sequential(
            nn.Conv2d(3, HIDDEN, 3, padding=1), nn.ReLU(), nn.Conv2d(HIDDEN, KEYPOINTS, 1)
        )
        self.softmax = SpatialSoftmax()
        with torch.no_grad():
            self.softmax.log_temperature.fill_(np.log(0.1))  # sharp from the start
        self.size = size
        self.window = window
        self.pairs = torch.triu_indices(KEYPOINTS, KEYPOINTS, 1)
        self.dim = 3 * KEYPOINTS + self.pairs.shape[1]

    def forward(self, image: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
        maps = self.maps(image.float() / 255.0)
        xy = self.softmax(maps).reshape(-1, KEYPOINTS, 2)  # [-1, 1], first to last pixel centre
        t = self.softmax.log_temperature.exp()
        pixels = [(xy + 1.0) * (self.size - 1) / 2.0]
        if self.window > 0:
            pixels.append(local_soft_argmax(maps, t, self.window))
            xy = pixels[-1] * 2.0 / (self.size - 1) - 1.0
        mass = torch.logsumexp(maps.flatten(2) / t, dim=-1) / 10.0
        i, j = self.pairs
        spacing = torch.log(torch.linalg.vector_norm(xy[:, i] - xy[:, j], dim=-1) + 1e-3)
        return pixels, torch.cat((xy.flatten(1), mass, spacing), dim=1)


class ProbeNet(nn.Module):
    """The views' keypoint features and the state -> (action (3), relative vector (3),
    standardised); the keypoints of each view in pixels."""

    def __init__(self, sizes: dict[str, int], window: int = 0) -> None:
        super().__init__()
        self.views = nn.ModuleDict({k: ViewKeypoints(s, window) for k, s in sizes.items()})
        width = sum(v.dim for v in self.views.values()) + 7
        self.trunk = nn.Sequential(nn.Linear(width, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU())
        self.head = nn.Linear(256, 6)
        self.register_buffer("mean", torch.zeros(width))
        self.register_buffer("std", torch.ones(width))
        self.register_buffer("relative_mean", torch.zeros(3))  # m: the relative head's units
        self.register_buffer("relative_std", torch.ones(3))

    def features(self, views: dict[str, torch.Tensor], state: torch.Tensor):
        found = {k: net(views[k]) for k, net in self.views.items()}
        x = torch.cat([f for _, f in found.values()] + [state], dim=1)
        return x, {k: p for k, (p, _) in found.items()}

    def forward(self, views: dict[str, torch.Tensor], state: torch.Tensor):
        x, keypoints = self.features(views, state)
        out = self.head(self.trunk((x - self.mean) / self.std))
        return out[:, :3], out[:, 3:], keypoints


def _batch(rows: Rows, index: np.ndarray) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    views = {k: torch.as_tensor(v[index]) for k, v in rows.views.items()}
    return views, torch.as_tensor(rows.state[index])


def fit(net: ProbeNet, rows: Rows, epochs: int, lr: float, supervise: bool, seed: int) -> None:
    """Module docstring, 3."""
    rng = np.random.default_rng(seed)
    n = len(rows.state)
    with torch.no_grad():
        x, _ = net.features(*_batch(rows, np.sort(rng.choice(n, min(n, 2048), replace=False))))
        net.mean.copy_(x.mean(0))
        net.std.copy_(x.std(0) + 1e-3)
        net.relative_mean.copy_(torch.as_tensor(rows.relative.mean(0)))
        net.relative_std.copy_(torch.as_tensor(rows.relative.std(0) + 1e-6))
    relative = (torch.as_tensor(rows.relative) - net.relative_mean) / net.relative_std
    action = torch.as_tensor(rows.action)
    points = {k: torch.as_tensor(v) for k, v in rows.points.items()}
    inside = {
        k: torch.as_tensor(np.all((v >= 0) & (v <= rows.views[k].shape[-1] - 1), axis=2))
        for k, v in rows.points.items()
    }
    optimizer = torch.optim.Adam(net.parameters(), lr=lr)
    per_epoch = max(1, n // BATCH)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimizer, lr, total_steps=epochs * per_epoch)
    net.train()
    for _ in range(epochs):
        order = rng.permutation(n)
        for b in range(per_epoch):
            index = np.sort(order[b * BATCH : (b + 1) * BATCH])
            a, r, keypoints = net(*_batch(rows, index))
            loss = ((a - action[index]) ** 2).mean() + ((r - relative[index]) ** 2).mean()
            if supervise:
                for k, found in keypoints.items():
                    f = points[k].shape[1]
                    for p in found:  # the whole view's keypoints and the local ones
                        err = ((p[:, :f] - points[k][index]) ** 2).sum(-1)
                        loss = loss + 0.01 * (inside[k][index] * err).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
    net.eval()


def measure(net: ProbeNet, rows: Rows) -> dict[str, object]:
    """Module docstring, 4 (the offline part)."""
    actions, relatives, found = [], [], {k: [] for k in rows.views}
    with torch.no_grad():
        for lo in range(0, len(rows.state), 512):
            a, r, keypoints = net(*_batch(rows, np.arange(lo, min(lo + 512, len(rows.state)))))
            actions.append(a.numpy())
            relatives.append(r.numpy())
            for k, p in keypoints.items():
                found[k].append(p[-1].numpy())  # the keypoints the features read
    predicted = np.concatenate(relatives) * net.relative_std.numpy() + net.relative_mean.numpy()
    error = np.abs(predicted - rows.relative).astype(float) * 1e3  # mm
    near = np.linalg.norm(rows.relative, axis=1) < NEAR
    report: dict[str, object] = {
        "rows": len(error),
        "action_mse": float(np.mean((np.concatenate(actions) - rows.action) ** 2)),
        "relative_median_mm": np.median(error, 0).round(1).tolist(),
        "relative_p90_mm": np.percentile(error, 90, 0).round(1).tolist(),
        "near_share": float(near.mean()),
    }
    if near.any():
        report["near_median_mm"] = np.median(error[near], 0).round(1).tolist()
        report["near_p90_mm"] = np.percentile(error[near], 90, 0).round(1).tolist()
    for k, p in found.items():
        target = rows.points[k]
        f = target.shape[1]
        err = np.linalg.norm(np.concatenate(p)[:, :f] - target, axis=-1)
        seen = np.all((target >= 0) & (target <= rows.views[k].shape[-1] - 1), axis=2)
        report[f"{k}_keypoint_median_px"] = [
            round(float(np.median(err[seen[:, j], j])), 2) if seen[:, j].any() else None
            for j in range(f)
        ]
    return report


def play(net: ProbeNet, scenario: str, options: dict[str, int], episodes: int) -> int:
    """The captures of the network on the scenario's first ``episodes`` validation seeds."""
    seeds = list(load_scenario(scenario).validation_seeds[:episodes])
    venv = make_env(scenario, options, autoreset_mode="Disabled")
    captured = 0
    try:
        for lo in range(0, episodes, NUM_ENVS):
            batch = seeds[lo : lo + NUM_ENVS]
            obs, _ = venv.reset(seed=batch + batch[:1] * (NUM_ENVS - len(batch)))
            ended = np.zeros(NUM_ENVS, dtype=bool)
            ended[len(batch) :] = True  # padding rows are played, not counted
            counted = ended.copy()
            while not ended.all():
                views = {k: torch.as_tensor(obs[k][:, -3:].copy()) for k in net.views}
                with torch.no_grad():
                    a, _, _ = net(views, torch.as_tensor(obs["state"]))
                obs, _, terminated, truncated, info = venv.step(np.clip(a.numpy(), -1, 1))
                now = (terminated | truncated) & ~counted
                success = np.asarray(info.get("is_success", np.zeros(NUM_ENVS, dtype=bool)))
                captured += int(np.sum(success & now))
                counted |= now
                ended |= terminated | truncated
    finally:
        venv.close()
    return captured


def probe(args: argparse.Namespace) -> dict[str, object]:
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    scenario = load_scenario(args.scenario)
    options = {"image_supersample": args.image_supersample}
    if args.ee_crop:
        options |= {"ee_crop": args.ee_crop, "ee_crop_scale": args.ee_crop_scale}
    start = time.perf_counter()
    train_seeds = scenario.training_seeds
    validation_seeds = scenario.validation_seeds[args.episodes :]
    train = collect(args.scenario, options, args.train_steps, train_seeds)
    validation = collect(args.scenario, options, args.validation_steps, validation_seeds)
    collected = time.perf_counter() - start
    net = ProbeNet({k: v.shape[-1] for k, v in train.views.items()}, args.window)
    fit(net, train, args.epochs, args.lr, not args.no_supervision, args.seed)
    report = {"options": options, "supervised": not args.no_supervision, "window": args.window,
              **measure(net, validation)}  # fmt: skip
    report["captured"] = play(net, args.scenario, options, args.episodes) if args.episodes else 0
    report["episodes"] = args.episodes
    report["collect_s"] = round(collected, 1)
    report["wall_clock_s"] = round(time.perf_counter() - start, 1)
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="paper")
    parser.add_argument("--ee-crop", type=int, default=0, help="crop side n, pixels (0: none)")
    parser.add_argument("--ee-crop-scale", type=int, default=3)
    parser.add_argument("--image-supersample", type=int, default=3)
    parser.add_argument("--train-steps", type=int, default=32000)
    parser.add_argument("--validation-steps", type=int, default=8000)
    parser.add_argument("--epochs", type=int, default=8)
    parser.add_argument("--lr", type=float, default=2e-3)
    parser.add_argument("--episodes", type=int, default=48, help="validation seeds played")
    parser.add_argument("--no-supervision", action="store_true",
                        help="no privileged keypoint targets")  # fmt: skip
    parser.add_argument("--window", type=int, default=0,
                        help="w > 0: the features read each map's soft-argmax over the (2w+1)^2 "
                        "pixels around its peak (both keypoints supervised)")  # fmt: skip
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="write the report here as JSON")
    args = parser.parse_args(argv)
    try:
        report = probe(args)
    except (ConfigError, ValueError) as error:
        print(f"pixel_keypoint_probe: {error}", file=sys.stderr)
        return 2
    text = json.dumps(report, indent=1)
    print(text)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
