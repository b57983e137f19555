"""What ``reset`` costs, and what the episode's physical-limit bound adds to it.

Times, per episode, in milliseconds of this process's CPU time (best of ``--repeats``):

* ``single``: ``CaptureEnv`` (the live target side, training's default), ``reset()`` unseeded
  after one seeded reset (training's resets), then ``physical_limit()``, which the env asks at
  every episode's end (``info["physical_limit_time"]``): ``reset``, ``bound`` and their sum.
* ``recorded``: the same with ``reuse_target_side=True`` (the target side recorded at reset).
* ``vector``: ``CaptureVectorEnv`` of ``--num-envs`` sub-envs (its own cache), ``reset`` with a
  list of new seeds: every sub-env's episode recorded in one batch (camera, EKF's first rows,
  bound); milliseconds per episode.

Only the public API is used, so the same script times two versions of the package (run it with
each on ``PYTHONPATH``)::

    python benchmarks/bench_reset.py                       # paper, every mode
    python benchmarks/bench_reset.py --scenario circular --modes single vector --episodes 400
    PYTHONPATH=/path/to/other/checkout python benchmarks/bench_reset.py --modes single

Pin it to one core (``taskset -c 0``) for steadier figures; BLAS is held to one thread here.
"""

from __future__ import annotations

import argparse
import os
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import capture_bench  # noqa: E402
from capture_bench.engine.cache import EpisodeCache  # noqa: E402
from capture_bench.envs.capture_env import CaptureEnv  # noqa: E402
from capture_bench.envs.vector_env import CaptureVectorEnv  # noqa: E402
from capture_bench.task.scenarios import list_scenarios  # noqa: E402

MODES = ("single", "recorded", "vector")


def single(scenario: str, episodes: int, recorded: bool) -> tuple[float, float]:
    """(reset, bound) CPU seconds per episode of a single env, unseeded resets."""
    env = CaptureEnv(scenario, reuse_target_side=recorded, episode_cache=EpisodeCache())
    env.reset(seed=0)
    env.physical_limit()
    reset = bound = 0.0
    for _ in range(episodes):
        start = time.process_time()
        env.reset()
        middle = time.process_time()
        env.physical_limit()
        end = time.process_time()
        reset += middle - start
        bound += end - middle
    env.close()
    return reset / episodes, bound / episodes


def vector(scenario: str, episodes: int, num_envs: int) -> float:
    """CPU seconds per episode of a vector env's seeded resets (new seeds each time)."""
    env = CaptureVectorEnv(num_envs, scenario)
    env.reset(seed=list(range(num_envs)))  # the first batch builds the world: not counted
    rounds = max(1, episodes // num_envs)
    start = time.process_time()
    for r in range(1, rounds + 1):
        env.reset(seed=list(range(r * num_envs, (r + 1) * num_envs)))
    spent = time.process_time() - start
    env.close()
    return spent / (rounds * num_envs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scenario", default="paper", choices=list_scenarios())
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--episodes", type=int, default=200, help="episodes per measurement")
    parser.add_argument("--num-envs", type=int, default=16, help="sub-envs of the vector env")
    parser.add_argument("--repeats", type=int, default=3, help="measurements; the best is shown")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.num_envs < 1 or args.repeats < 1:
        parser.error("--episodes, --num-envs and --repeats take whole numbers >= 1")
    print(
        f"capture-bench {capture_bench.__version__} ({os.path.dirname(capture_bench.__file__)}):"
        f" {args.scenario}, {args.episodes} episodes, CPU ms per episode, best of {args.repeats}"
    )
    print(f"{'mode':10s} {'reset':>8s} {'bound':>8s} {'total':>8s}")
    for mode in args.modes:
        if mode == "vector":
            best = min(
                vector(args.scenario, args.episodes, args.num_envs) for _ in range(args.repeats)
            )
            label = f"vector/{args.num_envs}"
            print(f"{label:10s} {best * 1e3:8.3f} {'-':>8s} {best * 1e3:8.3f}", flush=True)
            continue
        runs = [
            single(args.scenario, args.episodes, mode == "recorded") for _ in range(args.repeats)
        ]
        reset, bound = min(runs, key=sum)
        print(
            f"{mode:10s} {reset * 1e3:8.3f} {bound * 1e3:8.3f} {(reset + bound) * 1e3:8.3f}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
