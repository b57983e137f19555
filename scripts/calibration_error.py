"""What the rendered camera's lens and calibration error keys do, on validation seeds: the pixel
error of the nominal calibration's reprojection and the estimator's position error
(docs/rendered_camera.md, "Lens and calibration error").

    python scripts/calibration_error.py                        # 50 validation seeds each
    python scripts/calibration_error.py --seeds 20 --scenarios paper_rendered
    python scripts/calibration_error.py --scenarios paper --keys-from paper_rendered

For each rendered scenario, each setting of the keys (``off``: every lens and calibration key 0;
``lens``: the scenario's distortion only, known exactly to the estimator; one calibration error
key alone at the scenario's value; ``shipped``: the scenario as shipped) plays the paper's
controller (``incremental_ik``) on the first ``--seeds`` validation seeds (never a published
seed) and prints (``--keys-from``: the lens and calibration keys of another scenario, e.g. a
rendered scenario's on its analytic twin):

* **reprojection, px**: over every step of each episode, each marker the true camera sees on
  its sensor, |what the true camera records - where the nominal calibration (pose, f, principal
  point, distortion) predicts it|: RMS, 95th percentile and largest, from geometry alone (no
  detection error);
* **position error, mm**: the estimate's |X_T estimated - X_T true| at every step with an
  estimate: median and 95th percentile;
* the share of episodes captured, and the env's steps per second (agent and resets included).
"""

from __future__ import annotations

import time

import numpy as np

from capture_bench.agents import make_agent
from capture_bench.argparsing import OneLineParser
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.sensing.calibration import TrueCamera
from capture_bench.sensing.pixels import pixel_of, principal_point
from capture_bench.task.scenarios import ConfigError, Scenario, load_scenario

SCENARIOS = ("paper_rendered", "grasp_rendered")
LENS = ("distortion_k1", "distortion_k2", "distortion_p1", "distortion_p2")
SPREAD = (
    "calibration_focal",
    "calibration_principal_px",
    "calibration_k1",
    "calibration_rotation_deg",
    "calibration_position",
)


def settings(scenario: Scenario, keys_from: Scenario | None = None) -> dict[str, Scenario]:
    """The scenario with its lens and calibration keys (or ``keys_from``'s) off, the lens
    only, each calibration key alone (where set) and all of them."""
    cam = (scenario if keys_from is None else keys_from).camera
    off = dict.fromkeys((*LENS, *SPREAD), 0.0)
    out = {"off": scenario.replace(camera=off)}
    out["lens"] = scenario.replace(camera={**off, **{k: getattr(cam, k) for k in LENS}})
    for key in SPREAD:
        if getattr(cam, key):
            lens = {k: getattr(cam, k) for k in LENS}
            out[key] = scenario.replace(camera={**off, **lens, key: getattr(cam, key)})
    out["shipped"] = scenario.replace(camera={k: getattr(cam, k) for k in (*LENS, *SPREAD)})
    return out


def reprojection_px(lens: TrueCamera, points: np.ndarray) -> np.ndarray:
    """|recorded - predicted| pixels of global points (M, 3) the true camera sees on its sensor:
    recorded by the true camera, predicted by the nominal calibration."""
    true, nominal = lens.model, lens.nominal
    seen = true.visible(true.to_camera(points))
    points = points[seen]
    recorded = lens.measured_pixels(pixel_of(true.to_camera(points), true))
    centre = principal_point(nominal)
    scale = nominal.focal_length / nominal.pixel_pitch
    pinhole = (pixel_of(nominal.to_camera(points), nominal) - centre) / scale
    predicted = centre + scale * lens.nominal_distortion.apply(pinhole)
    return np.hypot(*(recorded - predicted).T)


def play(scenario: Scenario, seeds: list[int]) -> dict[str, float]:
    """Play ``seeds`` with incremental_ik: the reprojection and position errors, captures and
    steps per second."""
    env = CaptureEnv(scenario)
    pixels: list[np.ndarray] = []
    errors: list[float] = []
    captured = steps = 0
    start = time.perf_counter()
    try:
        for seed in seeds:
            obs, _ = env.reset(seed=seed)
            side = env.engine.sides.sides[0]
            lens = side.camera_episode.lens
            if lens is not None:
                ep = side.episode
                features = env.task.features
                markers = ep.position[:, None] + np.einsum("tij,nj->tni", ep.rotation, features)
                pixels.append(reprojection_px(lens, markers.reshape(-1, 3)))
            agent = make_agent("incremental_ik", env)
            done = False
            while not done:
                action, _ = agent.predict(obs)
                obs, _, terminated, truncated, info = env.step(action)
                done = terminated or truncated
                steps += 1
                if np.isfinite(info["estimate_position_error"]):
                    errors.append(float(info["estimate_position_error"]))
            captured += bool(info["is_success"])
    finally:
        env.close()
    elapsed = time.perf_counter() - start
    px = np.concatenate(pixels) if pixels else np.zeros(1)
    mm = 1000.0 * np.array(errors)
    return {
        "rms_px": float(np.sqrt(np.mean(px**2))),
        "p95_px": float(np.percentile(px, 95)),
        "max_px": float(px.max()),
        "median_mm": float(np.median(mm)),
        "p95_mm": float(np.percentile(mm, 95)),
        "captured": captured / len(seeds),
        "steps_per_s": steps / elapsed,
    }


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=50, help="validation seeds per scenario")
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    parser.add_argument(
        "--keys-from", help="take the lens and calibration keys from this scenario instead"
    )
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error(f"--seeds must be >= 1, got {args.seeds}")
    try:
        keys_from = None if args.keys_from is None else load_scenario(args.keys_from)
        scenarios = [load_scenario(name) for name in args.scenarios]
    except ConfigError as err:
        parser.error(str(err))
    print(
        "| scenario | keys | reprojection RMS, px | p95, px | max, px | position error median, "
        "mm | p95, mm | captured | steps/s |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name, scenario in zip(args.scenarios, scenarios, strict=True):
        seeds = list(scenario.validation_seeds)[: args.seeds]
        for label, variant in settings(scenario, keys_from).items():
            r = play(variant, seeds)
            print(
                f"| {name} | {label} | {r['rms_px']:.2f} | {r['p95_px']:.2f} | "
                f"{r['max_px']:.2f} | {r['median_mm']:.2f} | {r['p95_mm']:.2f} | "
                f"{r['captured']:.2f} | {r['steps_per_s']:.0f} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
