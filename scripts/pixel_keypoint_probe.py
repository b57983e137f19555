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
2. **Network.** Each view to keypoints by ``--reader`` (`ViewKeypoints`): ``softmax``, a 3 x 3
   convolution to 16 maps, a ReLU, a 1 x 1 convolution to `KEYPOINTS` maps and a spatial
   softmax (`capture_bench.agents.features.SpatialSoftmax`); ``centroid``, the same
   convolutions as detection logits that place a window on each map's peak, and a per-pixel
   network of the pixel's colour (`colour_channels`; ``centroid-rgb``: its RGB alone) whose
   non-negative weights' centroid in that window is the keypoint; ``marker``, train.py's
   reader of the markers (`capture_bench.agents.marker_reader.MarkerReader`); ``hand``, the
   markers' colours read by hand (`HandReader`, no parameters); ``oracle``, no
   image: the privileged points themselves plus Gaussian noise (what a head does with keypoints
   that precise). The features: the keypoints, how much each map found, and the log distances
   between keypoints (the markers' spacing, which is what tells depth); with ``--features
   markers`` those of the markers' keypoints alone (X_E's place is in the arm's state, and its
   log distance to a marker runs off to -7 as the two meet). An MLP (``--layers`` of
   ``--hidden`` units, 256 x 2) on those and the arm's state, standardised, gives the action and
   the relative vector.
3. **Fit.** Adam, one-cycle schedule, minibatches of 128: the action's squared error, the relative
   vector's (standardised) and, with privileged supervision, the squared pixel error of keypoint
   k against feature point k (then X_E) where that point lies inside the view (the ``marker``
   reader: its robust error, `keypoint_loss`, as train.py fits it; and for the centroid readers
   the detection logits' cross-entropy against it, `heatmap_loss`). With
   ``--head-epochs`` E the reader is then frozen, its features computed once, and the MLP fitted
   E more epochs on them (`fit_head`): the head's precision for the cost of an MLP's fit.
4. **Report.** On the validation rows: each supervised keypoint's median pixel error, the relative
   vector's median and 90th-percentile error per axis (all rows, and the rows within 50 mm of
   the target), the action's error, with the ``hand`` reader the share of the rows within 50 mm
   in which each marker shows (`shown_share`); then the network plays the first validation
   seeds of the scenario closed-loop and the captures are counted under the scenario's
   envelope.

``python scripts/pixel_keypoint_probe.py --ee-crop 75 --ee-crop-scale 3`` (docs/pixels.md,
"What a keypoint network reads").
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from capture_bench.agents.features import SpatialSoftmax
from capture_bench.agents.marker_reader import (
    MARKERS,
    WINDOW,
    HandReader,
    MarkerReader,
    colour_channels,
    feature_width,
    heatmap_loss,
    keypoint_features,
    keypoint_loss,
    local_centroid,
    shown_markers,
    to_unit,
    window_pixels,
)
from capture_bench.engine.engine import FrameStack
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
CENTROIDS = ("centroid", "centroid-rgb", "marker", "hand")  # readers whose keypoints are centroids


@dataclass
class Rows:
    """A data set: ``views`` name -> (N, 3, H, W) uint8; ``points`` name -> (N, F + 1, 2) view
    pixels; ``state`` (N, 7); ``action`` (N, 3), the teacher's; ``relative`` (N, 3), m."""

    views: dict[str, np.ndarray]
    points: dict[str, np.ndarray]
    state: np.ndarray
    action: np.ndarray
    relative: np.ndarray
    history: dict[str, np.ndarray] | None = None  # name -> (N, S, F + 1, 2): the last S steps'
    first: np.ndarray | None = None  # (N,) bool: the row is its episode's first step


def joined(a: Rows, b: Rows) -> Rows:
    """The rows of ``a`` then ``b`` (two collections, each starting its sub-envs' episodes, so
    `stacked` never reaches from one into the other)."""

    def cat(x: dict | None, y: dict | None) -> dict | None:
        return None if x is None else {k: np.concatenate((x[k], y[k])) for k in x}

    return Rows(
        cat(a.views, b.views), cat(a.points, b.points), np.concatenate((a.state, b.state)),
        np.concatenate((a.action, b.action)), np.concatenate((a.relative, b.relative)),
        cat(a.history, b.history), np.concatenate((a.first, b.first)),
    )  # fmt: skip


def stacked(x: torch.Tensor, first: np.ndarray, stack: int) -> torch.Tensor:
    """Each row's features ``x`` (N, D) and those of its sub-env's ``stack`` - 1 steps before,
    oldest first, (N, S, D), for rows in `collect`'s order (step after step, `NUM_ENVS` rows a
    step); an episode's first step stands in for the steps before it (a frame stack's rule)."""
    prev = np.where(first, np.arange(len(first)), np.arange(len(first)) - NUM_ENVS)
    index = [np.arange(len(first))]
    for _ in range(stack - 1):
        index.insert(0, prev[index[0]])
    return torch.stack([x[torch.as_tensor(i)] for i in index], dim=1)


def last_steps(stack: FrameStack, values: dict[str, np.ndarray], t: int) -> dict:
    """Each sub-env's ``values`` (name -> (N, ...)) of its last ``stack.k`` steps, oldest first,
    name -> (N, S, ...), after taking those of step ``t`` (`FrameStack.push`: an episode's first
    step fills all S with its own, as a frame stack does)."""
    got = stack.push(values, np.full(stack.n, t))
    return {k: v.reshape(v.shape[0], stack.k, -1, *v.shape[2:]) for k, v in got.items()}


class SeedList:
    """Episode seeds in a given order (an `EpisodeSeedSource`)."""

    def __init__(self, seeds: Sequence[int]) -> None:
        self._seeds = iter(seeds)

    def next(self) -> int:
        return next(self._seeds)


def make_env(scenario: str, options: dict[str, int], **kwargs: object) -> CaptureVectorEnv:
    return CaptureVectorEnv(NUM_ENVS, scenario, observation_source="pixels", **options, **kwargs)


def privileged_points(imager, venv: CaptureVectorEnv, state: np.ndarray, names) -> dict:
    """Where the target's feature points and X_E lie in each view named, name -> (N, F + 1, 2)
    view pixels (`WorkspaceImager.view_points`)."""
    features = venv.true_features()
    found = [
        imager.view_points(np.vstack([features[i], x_e]), x_e)
        for i, x_e in enumerate(state[:, 3:6].astype(float))
    ]
    return {k: np.stack([f[k] for f in found]).astype(np.float32) for k in names}


class Student:
    """The probe's network acting on `NUM_ENVS` sub-envs: each step's newest images (or, for an
    oracle, the privileged points of its last steps plus Gaussian noise of std ``noise``) and
    the arm's state -> actions in [-1, 1]; `restart` the sub-envs whose episode starts."""

    def __init__(self, net: ProbeNet, noise: float | None, rng: np.random.Generator) -> None:
        self.net, self.noise, self.rng = net, noise, rng
        self.points = list(net.views) if net.oracle else []  # the privileged points it reads
        points_stack = max(v.stack for v in net.views.values()) if net.oracle else 1
        self.history = FrameStack(NUM_ENVS, points_stack)
        self.recent = FrameStack(NUM_ENVS, net.head_stack)

    def restart(self, rows: np.ndarray) -> None:
        self.history.restart(rows)
        self.recent.restart(rows)

    def __call__(self, obs: dict, found: dict | None, t: int) -> np.ndarray:
        """The actions at step ``t`` from the observation and (an oracle's) privileged points."""
        if self.net.oracle:
            if self.history.k > 1:
                found = last_steps(self.history, found, t)
            views = {k: torch.as_tensor(_noisy(v, self.noise, self.rng)) for k, v in found.items()}
        else:
            views = {k: torch.as_tensor(obs[k][:, -3:].copy()) for k in self.net.views}
        with torch.no_grad():
            x, _, _ = self.net.features(views, torch.as_tensor(obs["state"]))
            if self.net.head_stack > 1:
                x = torch.as_tensor(last_steps(self.recent, {"x": x.numpy()}, t)["x"])
            a, _ = self.net.heads(x)
        return np.clip(a.numpy(), -1, 1)


def collect(
    scenario: str, options: dict[str, int], steps: int, seeds: Sequence[int], stack: int = 1,
    student: Student | None = None,
) -> Rows:  # fmt: skip
    """``steps`` rows of `dls` with DART noise (module docstring, 1) on episodes seeded from
    ``seeds`` in turn (one per sub-env reset); with ``stack`` > 1 each row also holds the
    privileged points of its last ``stack`` steps (`last_steps`). With a ``student`` the student
    acts (DAgger: the states it reaches, each labelled with the teacher's action there)."""
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
    state, action, relative, first = [], [], [], []
    history, recent = FrameStack(NUM_ENVS, stack), {k: [] for k in names}
    ended = np.zeros(NUM_ENVS, dtype=bool)  # NEXT_STEP autoreset: the step after an end resets
    starting = np.ones(NUM_ENVS, dtype=bool)  # the sub-envs whose episode starts this row
    obs, _ = venv.reset()
    try:
        for t in range(-(-steps // NUM_ENVS)):
            label = teacher(venv.estimate_observation())
            truth = venv.true_observation()
            found = privileged_points(imager, venv, obs["state"], names)
            history.restart(np.flatnonzero(starting))
            if student is not None:
                student.restart(np.flatnonzero(starting))
            last = last_steps(history, found, t) if stack > 1 else {}
            for k in names:
                frames[k].append(obs[k][:, -3:])  # the newest frame
                points[k].append(found[k])
                if stack > 1:
                    recent[k].append(last[k])
            state.append(obs["state"])
            action.append(label)
            relative.append(truth[:, SLICES["relative_position"]] * RELATIVE_SCALE)
            first.append(starting)
            if student is None:
                act = np.clip(label + noise * rng.standard_normal(label.shape), -1.0, 1.0)
            else:
                act = student(obs, found, t)
            obs, _, terminated, truncated, _ = venv.step(act.astype(np.float32))
            starting, ended = ended, terminated | truncated  # the ended sub-envs were reset
    finally:
        imager.close()
        venv.close()
    return Rows(
        {k: np.concatenate(v)[:steps] for k, v in frames.items()},
        {k: np.concatenate(v)[:steps] for k, v in points.items()},
        np.concatenate(state)[:steps],
        np.concatenate(action)[:steps].astype(np.float32),
        np.concatenate(relative)[:steps].astype(np.float32),
        {k: np.concatenate(v)[:steps] for k, v in recent.items()} if stack > 1 else None,
        np.concatenate(first)[:steps],
    )


def local_soft_argmax(maps: torch.Tensor, temperature: torch.Tensor, half: int) -> torch.Tensor:
    """Each map's (B, K, H, W) expected position under its softmax over the (2 half + 1)^2 pixels
    around its largest value (`window_pixels`), [x, y] in pixels, (B, K, 2): the background
    beyond the window has no weight to pull it."""
    rows, cols, values = window_pixels(maps, half)
    weights = torch.softmax(values / temperature, dim=-1)
    x = (weights * cols).sum(-1)
    y = (weights * rows).sum(-1)
    return torch.stack((x, y), dim=-1).float()


class ViewKeypoints(nn.Module):
    """One view (B, 3, H, W) uint8 -> its keypoints in pixels, a list of (B, K, 2), features
    (B, D) and, for the ``centroid`` reader, its detection logits (B, K, H, W), by ``reader``:

    * ``softmax``: a 3 x 3 convolution to `HIDDEN` maps, a ReLU and a 1 x 1 convolution to
      `KEYPOINTS` maps, then the whole view's spatial softmax (and with ``window`` > 0 the
      `local_soft_argmax` that the features read);
    * ``centroid``: the same convolutions give detection logits, whose largest value places a
      window of (2 ``window`` + 1)^2 pixels, and a per-pixel network of `colour_channels` (1 x 1
      convolutions, `HIDDEN` then `KEYPOINTS` maps, each followed by a ReLU) gives the weights
      whose `local_centroid` in that window is the keypoint;
    * ``marker``: `capture_bench.agents.marker_reader.MarkerReader`, the reader of train.py's
      ``marker_keypoints`` (as ``centroid`` with one map per marker and the weights' last
      activation a sharp softplus); its keypoints are the markers' alone;
    * ``hand``: `HandReader`, no parameters (the MLP alone is fitted).
    """

    def __init__(
        self, size: int, window: int = 0, reader: str = "softmax", read: int = KEYPOINTS
    ) -> None:
        super().__init__()
        self.reader = reader
        self.size = size
        if reader in ("marker", "hand"):
            # train.py's window where none given
            self.marker = MarkerReader(window or WINDOW) if reader == "marker" else HandReader()
            self.read = min(read, MARKERS)
            self.dim = feature_width(self.read)
            return
        self.read = read
        self.maps = nn.Sequential(
            nn.Conv2d(3, HIDDEN, 3, padding=1), nn.ReLU(), nn.Conv2d(HIDDEN, KEYPOINTS, 1)
        )
        self.colour = reader == "centroid"  # "centroid-rgb": the weights read RGB alone
        if reader.startswith("centroid"):
            self.weights = nn.Sequential(
                nn.Conv2d(10 if self.colour else 3, HIDDEN, 1),
                nn.ReLU(),
                nn.Conv2d(HIDDEN, KEYPOINTS, 1),
                nn.ReLU(),
            )
            with torch.no_grad():
                self.weights[2].bias.fill_(0.1)  # every weight alive at the start
        else:
            self.softmax = SpatialSoftmax()
            with torch.no_grad():
                self.softmax.log_temperature.fill_(np.log(0.1))  # sharp from the start
        self.size = size
        self.window = max(window, 1) if reader.startswith("centroid") else window
        self.dim = feature_width(read)

    def forward(self, image: torch.Tensor):
        x = image.float() / 255.0
        if self.reader in ("marker", "hand"):
            pixels, mass, logits = self.marker(x)
            unit = to_unit(pixels[:, : self.read], self.size)
            return [pixels], keypoint_features(unit, torch.log(mass[:, : self.read] + 1e-3)), logits
        maps = self.maps(x)
        if self.reader.startswith("centroid"):
            weights = self.weights(colour_channels(x) if self.colour else x)
            peak = maps.flatten(2).argmax(-1)
            pixels, mass = local_centroid(weights, self.window, peak)
            r = self.read
            unit = to_unit(pixels[:, :r], self.size)
            return [pixels], keypoint_features(unit, torch.log(mass[:, :r] + 1e-3)), maps
        xy = self.softmax(maps).reshape(-1, KEYPOINTS, 2)  # [-1, 1], first to last pixel centre
        t = self.softmax.log_temperature.exp()
        pixels = [(xy + 1.0) * (self.size - 1) / 2.0]
        if self.window > 0:
            pixels.append(local_soft_argmax(maps, t, self.window))
            xy = to_unit(pixels[-1], self.size)
        mass = torch.logsumexp(maps.flatten(2) / t, dim=-1) / 10.0
        return pixels, keypoint_features(xy[:, : self.read], mass[:, : self.read]), None


class OracleKeypoints(nn.Module):
    """One view's privileged points (B, F + 1, 2), view pixels, given in place of its image (or
    with ``stack`` > 1 those of the last S steps, (B, S, F + 1, 2)) -> the newest as the
    keypoints and `ViewKeypoints`'s features of each step (no mass): what the head does with
    keypoints as precise as the points given; ``leave_out`` k: the features read every point
    but point k (0: marker 1, the capture point)."""

    reader = "oracle"

    def __init__(
        self, size: int, points: int, stack: int = 1, read: int | None = None,
        leave_out: int | None = None,
    ) -> None:  # fmt: skip
        super().__init__()
        self.size = size
        self.stack = stack
        first = points if read is None else read
        self.read = [i for i in range(first) if i != leave_out]  # the points the features read
        self.dim = stack * feature_width(len(self.read))

    def forward(self, points: torch.Tensor):
        steps = points if self.stack > 1 else points[:, None]
        read = steps[:, :, self.read]
        zero = torch.zeros(read.shape[:1] + read.shape[2:3])
        found = [keypoint_features(to_unit(read[:, i], self.size), zero) for i in range(self.stack)]
        return [steps[:, -1]], torch.cat(found, dim=1), None


class ProbeNet(nn.Module):
    """The views' keypoint features and the state -> (action (3), relative vector (3),
    standardised), through ``depth`` layers of ``hidden`` units; the keypoints of each view in
    pixels. ``reader``: `ViewKeypoints`'s, or ``oracle`` (`OracleKeypoints` of ``points`` points,
    fed the privileged points, of the last ``stack`` steps). ``read``: the features read the
    first ``read`` keypoints alone (the feature points, not X_E, whose place the state gives);
    None: all of them; ``leave_out`` (an oracle's): one point the features do not read."""

    def __init__(
        self, sizes: dict[str, int], window: int | dict[str, int] = 0, reader: str = "softmax",
        points: int = 5, hidden: int = 256, depth: int = 2, stack: int = 1,
        read: int | None = None, leave_out: int | None = None,
    ) -> None:  # fmt: skip
        super().__init__()
        self.oracle = reader == "oracle"
        windows = window if isinstance(window, dict) else dict.fromkeys(sizes, window)
        self.views = nn.ModuleDict({
            k: OracleKeypoints(s, points, stack, read, leave_out) if self.oracle
            else ViewKeypoints(s, windows[k], reader, KEYPOINTS if read is None else read)
            for k, s in sizes.items()
        })  # fmt: skip
        width = sum(v.dim for v in self.views.values()) + 7
        self.width, self.hidden, self.depth, self.head_stack = width, hidden, depth, 1
        self.trunk, self.head = self._mlp(width)
        self.register_buffer("mean", torch.zeros(width))
        self.register_buffer("std", torch.ones(width))
        self.register_buffer("relative_mean", torch.zeros(3))  # m: the relative head's units
        self.register_buffer("relative_std", torch.ones(3))

    def features(self, views: dict[str, torch.Tensor], state: torch.Tensor):
        """The features (B, D), each view's keypoints (a list of (B, K, 2)) and each view's
        detection logits (None but for the ``centroid`` reader)."""
        found = {k: net(views[k]) for k, net in self.views.items()}
        x = torch.cat([f for _, f, _ in found.values()] + [state], dim=1)
        return x, {k: p for k, (p, _, _) in found.items()}, {k: m for k, (_, _, m) in found.items()}

    def _mlp(self, width: int) -> tuple[nn.Sequential, nn.Linear]:
        layers: list[nn.Module] = []
        for n in range(self.depth):
            layers += [nn.Linear(width if n == 0 else self.hidden, self.hidden), nn.ReLU()]
        return nn.Sequential(*layers), nn.Linear(self.hidden, 6)

    def stack_head(self, stack: int) -> None:
        """A new MLP that reads the features of the last ``stack`` steps (`heads`)."""
        self.head_stack = stack
        self.trunk, self.head = self._mlp(stack * self.width)

    def heads(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The action and the relative vector from features (B, D), or with a head stack
        (`fit_head`) the features of each row's last ``head_stack`` steps (B, S, D)."""
        out = self.head(self.trunk(((x - self.mean) / self.std).flatten(1)))
        return out[:, :3], out[:, 3:]

    def forward(self, views: dict[str, torch.Tensor], state: torch.Tensor):
        x, keypoints, _ = self.features(views, state)
        return *self.heads(x), keypoints


def _batch(
    rows: Rows,
    index: np.ndarray,
    noise: float | None = None,
    rng: np.random.Generator | None = None,
) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """The rows' views, or with ``noise`` (an oracle's) their privileged points (of the last
    steps where the rows hold them) plus Gaussian noise of that std, pixels; and their states."""
    if noise is None:
        views = {k: torch.as_tensor(v[index]) for k, v in rows.views.items()}
    else:
        points = rows.points if rows.history is None else rows.history
        views = {k: torch.as_tensor(_noisy(v[index], noise, rng)) for k, v in points.items()}
    return views, torch.as_tensor(rows.state[index])


def _noisy(points: np.ndarray, noise: float, rng: np.random.Generator) -> np.ndarray:
    return (points + noise * rng.standard_normal(points.shape)).astype(np.float32)


def fit(
    net: ProbeNet, rows: Rows, epochs: int, lr: float, supervise: bool, seed: int,
    noise: float | None = None,
) -> None:  # fmt: skip
    """Module docstring, 3 (an oracle's points, ``noise``, are not supervised)."""
    rng = np.random.default_rng(seed)
    n = len(rows.state)
    supervise = supervise and not net.oracle
    # squared pixel error's weight: a centroid's keypoints, sub-pixel once detected, weigh more
    weight = 1.0 if any(v.reader in CENTROIDS for v in net.views.values()) else 0.01
    with torch.no_grad():
        sample = np.sort(rng.choice(n, min(n, 2048), replace=False))
        x, _, _ = net.features(*_batch(rows, sample, noise, rng))
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
            x, keypoints, logits = net.features(*_batch(rows, index, noise, rng))
            a, r = net.heads(x)
            loss = ((a - action[index]) ** 2).mean() + ((r - relative[index]) ** 2).mean()
            if supervise:
                for k, found in keypoints.items():
                    for p in found:  # the whole view's keypoints and the local ones
                        f = min(points[k].shape[1], p.shape[1])  # the marker reader: no X_E
                        target, seen = points[k][index, :f], inside[k][index, :f]
                        if net.views[k].reader == "marker":  # fitted as train.py fits it
                            loss = loss + keypoint_loss(p[:, :f], target, seen)
                            continue
                        err = ((p[:, :f] - target) ** 2).sum(-1)
                        loss = loss + weight * (seen * err).mean()
                    if logits[k] is not None:
                        f = min(points[k].shape[1], logits[k].shape[1])
                        target, seen = points[k][index, :f], inside[k][index, :f]
                        loss = loss + heatmap_loss(logits[k], target, seen)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
    net.eval()


def all_features(
    net: ProbeNet, rows: Rows, noise: float | None = None, rng: np.random.Generator | None = None
) -> tuple[torch.Tensor, dict[str, list[torch.Tensor]]]:
    """Every row's features (N, D) and each view's keypoints (the list `ViewKeypoints` gives),
    in batches, without gradients."""
    n = len(rows.state)
    xs, keypoints = [], {}
    with torch.no_grad():
        for lo in range(0, n, 512):
            x, found, _ = net.features(*_batch(rows, np.arange(lo, min(lo + 512, n)), noise, rng))
            xs.append(x)
            for k, p in found.items():
                keypoints.setdefault(k, []).append(p)
    return torch.cat(xs), {k: [torch.cat(p) for p in zip(*v)] for k, v in keypoints.items()}


def fit_head(
    net: ProbeNet, rows: Rows, epochs: int, lr: float, seed: int, noise: float | None = None,
    stack: int = 1,
) -> None:  # fmt: skip
    """The MLP alone, ``epochs`` more epochs on the views' features computed once (an oracle's
    noise drawn once per row), the action's and the relative vector's squared errors. With
    ``stack`` > 1 a new MLP (same layers) reads the features of each row's last ``stack`` steps
    (`stacked`; ``net.head_stack``), as a frame stack read by the same reader frame by frame
    would give them."""
    rng = np.random.default_rng(seed + 1)
    x, _ = all_features(net, rows, noise, rng)
    if stack > 1:
        x = stacked(x, rows.first, stack)
        net.stack_head(stack)
    relative = (torch.as_tensor(rows.relative) - net.relative_mean) / net.relative_std
    params = [*net.trunk.parameters(), *net.head.parameters()]
    fit_on_features(net.heads, params, x, torch.as_tensor(rows.action), relative, epochs, lr, rng)


def fit_on_features(
    heads: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]], params: list,
    x: torch.Tensor, action: torch.Tensor, relative: torch.Tensor, epochs: int, lr: float,
    rng: np.random.Generator,
) -> None:  # fmt: skip
    """``epochs`` epochs of Adam on ``params`` (one-cycle schedule, minibatches of `BATCH` in
    ``rng``'s order): ``heads`` of the features ``x`` (N, ...) against the actions and the
    standardised relative vectors, the sum of their mean squared errors."""
    n = len(x)
    optimizer = torch.optim.Adam(params, lr=lr)
    per_epoch = max(1, n // BATCH)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimizer, lr, total_steps=epochs * per_epoch)
    for _ in range(epochs):
        order = torch.as_tensor(rng.permutation(n))
        for b in range(per_epoch):
            index = order[b * BATCH : (b + 1) * BATCH]
            a, r = heads(x[index])
            loss = ((a - action[index]) ** 2).mean() + ((r - relative[index]) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()


def shown_share(views: np.ndarray) -> np.ndarray:
    """The share of frames (N, 3, H, W) uint8 in which each marker shows, (`MARKERS`,): its
    `HandReader` weight at least `SHOWN` of the frame's largest marker's (the markers are the
    same size and about as far from the lens, so a marker the gripper or the block hides in
    part weighs less)."""
    reader, masses = HandReader(), []
    with torch.no_grad():
        for lo in range(0, len(views), 512):
            masses.append(reader(torch.as_tensor(views[lo : lo + 512]) / 255.0)[1])
    mass = torch.cat(masses).numpy()
    return np.mean(shown_markers(mass), axis=0)


def measure(net: ProbeNet, rows: Rows, noise: float | None = None) -> dict[str, object]:
    """Module docstring, 4 (the offline part)."""
    actions, relatives = [], []
    x, keypoints = all_features(net, rows, noise, np.random.default_rng(1))
    if net.head_stack > 1:
        x = stacked(x, rows.first, net.head_stack)
    with torch.no_grad():
        for lo in range(0, len(rows.state), 512):
            a, r = net.heads(x[lo : lo + 512])
            actions.append(a.numpy())
            relatives.append(r.numpy())
    found = {k: [p[-1].numpy()] for k, p in keypoints.items()}  # the keypoints the features read
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
    for k, view in net.views.items():
        if getattr(view, "reader", None) == "hand" and near.any():
            report[f"{k}_near_shown_share"] = shown_share(rows.views[k][near]).round(3).tolist()
    for k, p in found.items():
        found_k = np.concatenate(p)
        f = min(rows.points[k].shape[1], found_k.shape[1])
        target = rows.points[k][:, :f]
        err = np.linalg.norm(found_k[:, :f] - target, axis=-1)
        seen = np.all((target >= 0) & (target <= rows.views[k].shape[-1] - 1), axis=2)
        report[f"{k}_keypoint_median_px"] = [
            round(float(np.median(err[seen[:, j], j])), 2) if seen[:, j].any() else None
            for j in range(f)
        ]
    return report


def play(
    net: ProbeNet | None, scenario: str, options: dict[str, int], episodes: int,
    noise: float | None = None, student: Student | None = None,
) -> int:  # fmt: skip
    """The captures of the network on the scenario's first ``episodes`` validation seeds (an
    oracle's fed the privileged points plus Gaussian noise of std ``noise``, pixels), or of
    another ``student`` (its ``restart`` and call as `Student`'s; ``points``: the views whose
    privileged points it reads)."""
    seeds = list(load_scenario(scenario).validation_seeds[:episodes])
    venv = make_env(scenario, options, autoreset_mode="Disabled")
    imager = CaptureTask(load_scenario(scenario), observation_source="pixels", **options).imager()
    if student is None:
        student = Student(net, noise, np.random.default_rng(2))
    captured = 0
    try:
        for lo in range(0, episodes, NUM_ENVS):
            batch = seeds[lo : lo + NUM_ENVS]
            obs, _ = venv.reset(seed=batch + batch[:1] * (NUM_ENVS - len(batch)))
            student.restart(np.arange(NUM_ENVS))
            t = 0
            ended = np.zeros(NUM_ENVS, dtype=bool)
            ended[len(batch) :] = True  # padding rows are played, not counted
            counted = ended.copy()
            while not ended.all():
                found = (
                    privileged_points(imager, venv, obs["state"], student.points)
                    if student.points else None
                )  # fmt: skip
                obs, _, terminated, truncated, info = venv.step(student(obs, found, t))
                now = (terminated | truncated) & ~counted
                success = np.asarray(info.get("is_success", np.zeros(NUM_ENVS, dtype=bool)))
                captured += int(np.sum(success & now))
                counted |= now
                ended |= terminated | truncated
                t += 1
    finally:
        imager.close()
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
    stack = args.stack if args.reader == "oracle" else 1
    train = collect(args.scenario, options, args.train_steps, train_seeds, stack)
    validation = collect(args.scenario, options, args.validation_steps, validation_seeds, stack)
    collected = time.perf_counter() - start
    sizes = {k: v.shape[-1] for k, v in train.views.items()}
    points = next(iter(train.points.values())).shape[1]
    windows = {"image": args.window}
    if args.ee_crop:  # the same field of sensor pixels around a keypoint in the crop
        imager = CaptureTask(scenario, observation_source="pixels", **options).imager()
        windows["ee_image"] = -(-args.window * imager.scale // args.ee_crop_scale)
        imager.close()
    read = points - 1 if args.features == "markers" else None  # the last point is X_E
    leave_out = None if args.leave_out is None else args.leave_out - 1
    net = ProbeNet(
        sizes, windows, args.reader, points, args.hidden, args.layers, stack, read, leave_out
    )
    noise = args.oracle_noise if args.reader == "oracle" else None
    fit(net, train, args.epochs, args.lr, not args.no_supervision, args.seed, noise)
    if args.head_epochs:
        fit_head(net, train, args.head_epochs, args.lr, args.seed, noise, args.head_stack)
    rounds = []
    for r in range(args.dagger):  # the student's own states, labelled by the teacher
        captured = play(net, args.scenario, options, args.episodes, noise)
        rounds.append({"rows": len(train.state), "captured": captured})
        seeds = train_seeds[len(train_seeds) - (r + 1) * 100_000 :]  # not the first collection's
        student = Student(net, noise, np.random.default_rng(args.seed + 10 + r))
        train = joined(train, collect(args.scenario, options, args.dagger_steps, seeds, stack,
                                      student))  # fmt: skip
        if args.head_epochs:  # the reader stays as fitted, the head is fitted again
            fit_head(net, train, args.head_epochs, args.lr, args.seed, noise, args.head_stack)
        else:
            fit(net, train, args.epochs, args.lr, not args.no_supervision, args.seed, noise)
    report = {"options": options, "supervised": not args.no_supervision, "window": windows,
              **({"leave_out": args.leave_out} if args.leave_out is not None else {}),
              "reader": args.reader, "features": args.features, "mlp": [args.hidden] * args.layers,
              "train_rows": len(train.state), "epochs": args.epochs,
              "head_epochs": args.head_epochs, "head_stack": net.head_stack, "stack": stack,
              "dagger_rounds": rounds,
              **measure(net, validation, noise)}  # fmt: skip
    if noise is not None:
        report["oracle_noise_px"] = noise
    report["captured"] = (
        play(net, args.scenario, options, args.episodes, noise) if args.episodes else 0
    )
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
    parser.add_argument("--head-epochs", type=int, default=0,
                        help="E > 0: then E epochs of the MLP alone on the frozen reader's "
                        "features")  # fmt: skip
    parser.add_argument("--episodes", type=int, default=48, help="validation seeds played")
    parser.add_argument("--no-supervision", action="store_true",
                        help="no privileged keypoint targets")  # fmt: skip
    parser.add_argument("--window", type=int, default=0,
                        help="w > 0: the features read each map's soft-argmax over the (2w+1)^2 "
                        "pixels around its peak (both keypoints supervised)")  # fmt: skip
    parser.add_argument("--reader",
                        choices=("softmax", "centroid", "centroid-rgb", "marker", "hand",
                                 "oracle"),
                        default="softmax",
                        help="how each view's keypoints are read: a spatial softmax, local "
                        "centroids of non-negative maps of each pixel's colour (centroid-rgb: of "
                        "its RGB alone; marker: train.py's marker_keypoints reader; hand: the "
                        "markers' colours read by hand, no parameters), or the true "
                        "points plus "
                        "--oracle-noise (what a head does with such keypoints)")  # fmt: skip
    parser.add_argument("--head-stack", type=int, default=1,
                        help="S > 1 (with --head-epochs): the head-only fit's new MLP reads "
                        "the features of the last S steps")  # fmt: skip
    parser.add_argument("--stack", type=int, default=1,
                        help="the oracle reads the points of the last S steps (noise drawn "
                        "for each)")  # fmt: skip
    parser.add_argument("--oracle-noise", type=float, default=0.0,
                        help="std of the noise on the oracle's points, view pixels")  # fmt: skip
    parser.add_argument("--features", choices=("all", "markers"), default="all",
                        help="what the head reads of each view: every keypoint, or the "
                        "markers' alone (X_E's place is in the arm's state)")  # fmt: skip
    parser.add_argument("--dagger", type=int, default=0,
                        help="R > 0: then R rounds in which the network acts on training seeds, "
                        "the teacher labels the states it reaches, and the head (the whole "
                        "network without --head-epochs) is fitted again on all rows")  # fmt: skip
    parser.add_argument("--dagger-steps", type=int, default=16000,
                        help="rows each DAgger round adds")  # fmt: skip
    parser.add_argument("--leave-out", type=int,
                        help="marker k (1-4) whose point the oracle's features do not read "
                        "(1: the capture point, which the gripper hides)")  # fmt: skip
    parser.add_argument("--hidden", type=int, default=256, help="units of each layer of the MLP")
    parser.add_argument("--layers", type=int, default=2, help="layers of the MLP")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="write the report here as JSON")
    args = parser.parse_args(argv)
    if args.leave_out is not None and (args.reader != "oracle" or not 1 <= args.leave_out <= 4):
        print("pixel_keypoint_probe: --leave-out takes a marker 1-4 with --reader oracle; got "
              f"{args.leave_out} with --reader {args.reader}", file=sys.stderr)  # fmt: skip
        return 2
    return run_and_report("pixel_keypoint_probe", probe, args, argv)


def run_and_report(
    name: str, run: Callable[[argparse.Namespace], dict], args: argparse.Namespace,
    argv: list[str] | None,
) -> int:  # fmt: skip
    """``run(args)``'s report, its command first (``scripts/<name>.py`` and ``argv``), printed
    and written to ``args.out`` as JSON; a configuration error is one line on stderr and exit
    code 2."""
    words = sys.argv[1:] if argv is None else argv
    try:
        report = {"command": shlex.join(["python", f"scripts/{name}.py", *words]), **run(args)}
    except (ConfigError, ValueError) as error:
        print(f"{name}: {error}", file=sys.stderr)
        return 2
    text = json.dumps(report, indent=1)
    print(text)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
