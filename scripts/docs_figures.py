"""Draw the documentation's pictures of what the sensors see, into ``docs/figures/``:

    python scripts/docs_figures.py              # both figures, published seed 1000000
    python scripts/docs_figures.py --seed 1000003 --out /tmp/figures

* ``rendered_camera_view.png`` (``docs/rendered_camera.md``): the rendered camera's 1280 x 960
  image of a ``paper_rendered`` episode's first frame (the arm at its home pose, the target at
  reset), left whole, right enlarged around the target's four markers, with the detector's
  answer drawn over it: a ring on each marker found, a cross where a marker's projection falls
  but the detector refused it, labelled with the reason (``capture_bench.sensing.detector``).
  The frame and the detections are those of `RenderedSceneCamera` with the scenario's keys,
  rendered as one full frame (its windows' pixels are the full frame's).
* ``pixel_observation.png`` (``docs/pixels.md``): the first observation of
  ``gym.make("CaptureBench/Paper-v1", observation_source="pixels")`` (the scenario the shipped
  pixel policies were trained on), left the camera's whole frame of the same scene with the
  crop the image is taken from, right the 84 x 84 image itself, each pixel drawn as a square
  (nearest-neighbour). The script checks that the image it draws is the env's observation.

Each figure is written whole or not at all; the script prints the paths it wrote. A few seconds
on one core.
"""

from __future__ import annotations

import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import capture_bench  # noqa: F401  (registers the environments)
from capture_bench.argparsing import OneLineParser
from capture_bench.files import atomic_write, check_writable
from capture_bench.sensing.detector import FOUND, STATUS_NAMES
from capture_bench.sensing.pixels import image_plane_to_pixel
from capture_bench.sensing.render_camera import render_frame
from capture_bench.sensing.rendered_sensor import RenderSettings
from capture_bench.sensing.scene_camera import RenderedSceneCamera
from capture_bench.sensing.workspace_image import IMAGE_MARKER_RADIUS, crop_window
from capture_bench.sim.markers import MARKER_COLOURS
from capture_bench.sim.world import World
from capture_bench.task.scenarios import ConfigError

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "docs" / "figures"
DEFAULT_SEED = 1_000_000  # the first published evaluation seed of paper and paper_rendered
CAMERA_FIGURE = "rendered_camera_view.png"
PIXEL_FIGURE = "pixel_observation.png"
MARKER_NAMES = ("red", "green", "cyan", "magenta")  # MARKER_COLOURS, in order
ZOOM_MARGIN_PX = 45  # sensor pixels around the markers' projections in the enlarged panel
DPI = 100


def _first_frame(env_id: str, seed: int, **kwargs) -> tuple[gym.Env, dict]:
    env = gym.make(env_id, **kwargs)
    obs, _ = env.reset(seed=seed)
    return env, obs


def _save(fig, path: Path) -> None:
    atomic_write(path, writer=lambda tmp: fig.savefig(tmp, format="png", dpi=DPI))


def camera_figure(seed: int, path: Path) -> None:
    """The rendered camera's first frame of ``paper_rendered`` with its detections."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Rectangle

    env, _ = _first_frame("CaptureBench/PaperRendered-v1", seed)
    sim = env.unwrapped
    trajectory, theta = sim.plan.trajectory, sim.joint_angles
    env.close()
    camera = RenderedSceneCamera.for_scenario(sim.scenario, windowed=False)
    try:

        def pose_at(t: float):
            return trajectory.position(t), trajectory.rotation(t)

        image = camera.image(pose_at, 0.0, lambda t: theta, 0)
        found = camera.detect(pose_at, 0.0, lambda t: theta, 0)
        model = camera.model
        centres = trajectory.position(0.0) + camera.features @ trajectory.rotation(0.0).T
        truth = image_plane_to_pixel(model.project(model.to_camera(centres)), model)
    finally:
        camera.close()

    (u0, v0), (u1, v1) = truth.min(axis=0) - ZOOM_MARGIN_PX, truth.max(axis=0) + ZOOM_MARGIN_PX
    side = max(u1 - u0, (v1 - v0) * 4 / 3)  # the zoom keeps the sensor's 4:3
    cu, cv = (u0 + u1) / 2, (v0 + v1) / 2
    zoom = (cu - side / 2, cu + side / 2, cv - side * 3 / 8, cv + side * 3 / 8)

    fig = Figure(figsize=(10, 3.9), layout="constrained")
    whole, near = fig.subplots(1, 2, width_ratios=(1, 1))
    height, width = image.shape[:2]
    whole.imshow(image, interpolation="antialiased")
    whole.add_patch(
        Rectangle((zoom[0], zoom[2]), side, side * 3 / 4, fill=False, ec="black", lw=1, ls="--")
    )
    whole.set_title(f"the camera's {width} x {height} image (dashed: enlarged)")
    fig.suptitle(f"paper_rendered, seed {seed}, first frame")
    near.imshow(image, interpolation="nearest")
    near.set_xlim(zoom[0], zoom[1])
    near.set_ylim(zoom[3], zoom[2])
    near.set_title("the detector's answer per marker")
    middle = truth.mean(axis=0)
    lines = []
    for i, name in enumerate(MARKER_NAMES):
        colour = np.clip(np.array(MARKER_COLOURS[i][:3], dtype=float) * 0.75, 0, 1)
        if found.status[i] == FOUND:
            u, v = found.pixels[i]
            near.add_patch(Circle((u, v), 9, fill=False, ec="limegreen", lw=2))
            lines.append(f"{i} {name}: found")
        else:
            u, v = truth[i]
            near.add_patch(Circle((u, v), 9, fill=False, ec="red", lw=2, ls=(0, (2, 1.5))))
            lines.append(f"{i} {name}: missing ({STATUS_NAMES[found.status[i]]})")
        away = np.array([u, v]) - middle
        away = 16 * away / max(float(np.hypot(*away)), 1e-9)
        near.annotate(
            str(i),
            (u, v),
            xytext=(away[0], -away[1]),  # points: y up; the image's v runs down
            textcoords="offset points",
            ha="center",
            va="center",
            fontsize=11,
            fontweight="bold",
            color=colour,
        )
    near.text(
        0.98,
        0.03,
        "\n".join(lines),
        transform=near.transAxes,
        ha="right",
        va="bottom",
        fontsize=9,
        bbox={"facecolor": "white", "edgecolor": "0.7"},
    )
    for ax in (whole, near):
        ax.set_xticks([])
        ax.set_yticks([])
    _save(fig, path)


def pixel_figure(seed: int, path: Path) -> None:
    """The pixel env's first observation on ``paper`` beside the camera's whole frame."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    env, obs = _first_frame("CaptureBench/Paper-v1", seed, observation_source="pixels")
    sim = env.unwrapped
    trajectory, theta = sim.plan.trajectory, sim.joint_angles
    scenario, model = sim.scenario, sim.camera_model
    env.close()
    observation = np.asarray(obs["image"]).transpose(1, 2, 0)  # (84, 84, 3), row-major RGB
    size = (observation.shape[1], observation.shape[0])
    x, y, z = (float(v) for v in scenario.camera.light_direction)
    lighting = RenderSettings(
        light_direction=(x, y, z) if any((x, y, z)) else None,
        light_intensity=scenario.camera.light_intensity,
    ).lighting()
    world = World(sim.task.features, marker_radius=IMAGE_MARKER_RADIUS)
    try:
        world.set_joint_positions(np.asarray(theta, dtype=float).tolist())
        world.set_target_pose(trajectory.position(0.0), trajectory.rotation(0.0))
        width, height = model.resolution
        wide = render_frame(world.client, model, (0, width, 0, height), lighting, size=(640, 480))
        window = crop_window(model, size)
        again = render_frame(world.client, model, window, lighting, size=size)
    finally:
        world.close()
    if not np.array_equal(again, observation):
        raise RuntimeError("the image drawn is not the env's observation: the renderers differ")

    fig = Figure(figsize=(10, 4.1), layout="constrained")
    left, right = fig.subplots(1, 2, width_ratios=(4 / 3, 1))
    scale = wide.shape[1] / width  # image pixels per sensor pixel
    left.imshow(wide, interpolation="antialiased")
    u0, u1, v0, v1 = window
    left.add_patch(
        Rectangle(
            ((u0 - 0.5) * scale, (v0 - 0.5) * scale),
            (u1 - u0) * scale,
            (v1 - v0) * scale,
            fill=False,
            ec="black",
            lw=1,
            ls="--",
        )
    )
    left.set_title(f"the camera's {width} x {height} frame (dashed: the crop)")
    right.imshow(observation, interpolation="nearest")
    right.set_title(f"what the agent sees: obs['image'], {size[0]} x {size[1]}")
    fig.suptitle(f"paper with observation_source='pixels', seed {seed}, first observation")
    for ax in (left, right):
        ax.set_xticks([])
        ax.set_yticks([])
    _save(fig, path)


def main(argv: list[str] | None = None) -> int:
    """Draw both figures; returns the exit status (2: bad input, one line on stderr)."""
    parser = OneLineParser(
        prog="docs_figures.py", description=" ".join(__doc__.split("\n\n")[0].split())
    )
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the figures' folder")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED, help="the episode's seed")
    args = parser.parse_args(argv)
    try:
        if args.seed < 0:
            raise ConfigError(f"--seed {args.seed}: a seed is a whole number >= 0")
        if args.out.exists() and not args.out.is_dir():
            raise ConfigError(f"--out {args.out}: not a folder; give the figures' folder")
        args.out.mkdir(parents=True, exist_ok=True)
        check_writable(args.out, "--out")
    except (ConfigError, OSError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    for draw, name in ((camera_figure, CAMERA_FIGURE), (pixel_figure, PIXEL_FIGURE)):
        draw(args.seed, args.out / name)
        print(args.out / name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
