"""Env steps per second with the rendered camera (1280 x 960 at full pixel density), one core:

    taskset -c 0 python benchmarks/bench_rendered_env.py --seeds 20 [--clock cpu]
        [--set camera.exposure=0 ...]

The paper's controller plays validation seeds of each rendered scenario three ways:

* ``live``: ``CaptureEnv(scenario)``: every frame rendered, with the arm, in windows around the
  markers (`RenderedSceneCamera`, no store);
* ``first agent``: ``reuse_target_side=True``, a fresh cache: frames the arm cannot reach are
  rendered without it and kept by seed; the others with it;
* ``next agent``: the same seeds again (what every agent after the first costs in an
  evaluation): kept frames reused, only frames the arm may reach rendered;
* ``full frames``: the reference, every frame rendered in full (``--full``, slow).

Steps/s count the env's steps with the agent's time and resets included, over wall time, or
over this process's CPU time with ``--clock cpu`` (on a machine shared with other jobs).
"""

from __future__ import annotations

import argparse
import os
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from capture_bench.agents import make_agent  # noqa: E402
from capture_bench.engine.cache import EpisodeCache  # noqa: E402
from capture_bench.envs.capture_env import CaptureEnv  # noqa: E402
from capture_bench.sensing.scene_camera import RenderedSceneCamera  # noqa: E402
from capture_bench.task.scenarios import ConfigError, load_scenario, with_settings  # noqa: E402

CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


def steps_per_second(
    env: CaptureEnv, seeds: list[int], clock: str = "wall"
) -> tuple[float, int, dict[str, int]]:
    """Play the seeds with incremental_ik: (steps/s, steps, the camera's render counts), timed
    by ``clock`` (``wall``, or ``cpu``: this process's CPU time, for a shared machine)."""
    now = CLOCKS[clock]
    steps, start = 0, now()
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        agent = make_agent("incremental_ik", env)
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(agent.predict(obs)[0])
            steps += 1
            done = terminated or truncated
    seconds = now() - start
    camera = env.engine.sides.camera
    return steps / seconds, steps, dict(camera.renders) if camera else {}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=20, help="validation seeds per scenario")
    parser.add_argument("--scenarios", nargs="+", default=["paper_rendered", "grasp_rendered"])
    parser.add_argument("--full", action="store_true", help="also time full-frame rendering")
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="wall")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="a scenario key to change in each scenario, e.g. camera.exposure=0 (repeatable)",
    )
    args = parser.parse_args()
    for name in args.scenarios:
        try:
            scenario = with_settings(load_scenario(name), args.set)
        except ConfigError as exc:
            parser.error(str(exc))
        seeds = list(scenario.validation_seeds[: args.seeds])
        rows = []
        live = CaptureEnv(scenario)
        rows.append(("live", *steps_per_second(live, seeds, args.clock)))
        live.close()
        shared = CaptureEnv(scenario, reuse_target_side=True, episode_cache=EpisodeCache(100))
        rows.append(("first agent", *steps_per_second(shared, seeds, args.clock)))
        camera = shared.engine.sides.camera
        camera.renders = dict.fromkeys(camera.renders, 0)
        rows.append(("next agent", *steps_per_second(shared, seeds, args.clock)))
        shared.close()
        if args.full:
            full = CaptureEnv(scenario)
            full.engine.sides.camera.close()
            full.engine.sides.camera = RenderedSceneCamera.for_scenario(
                full.task.scenario, windowed=False
            )
            rows.append(("full frames", *steps_per_second(full, seeds[:3], args.clock)))
            full.close()
        for label, rate, steps, renders in rows:
            print(f"{name:16s} {label:12s} {rate:8.1f} steps/s  ({steps} steps; frames {renders})")


if __name__ == "__main__":
    main()
