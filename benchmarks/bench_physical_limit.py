"""Micro-benchmark of the physical-limit bound: one episode at a time vs batches of G episodes.

Usage::

    python benchmarks/bench_physical_limit.py [--episodes 192] [--groups 16 64] [--repeats 3]
        [--clock cpu|wall]

Episodes come from every shipped scenario, an equal share each (``CaptureEnv(name).reset(seed=s)``),
with the arguments ``CaptureEnv.physical_limit`` passes (the scenario's tolerance and capture
envelope: hold, v_max, the target's velocity). Prints milliseconds per episode (best of
``--repeats``; CPU time of this process by default) for `physical_limit` called episode
by episode and for `physical_limits` on groups of up to G episodes of one scenario (the
envelope is a scenario's), and checks that both give the same times.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.task.physical_limit import PhysicalLimit, physical_limit, physical_limits
from capture_bench.task.scenarios import list_scenarios

CLOCKS = {"cpu": time.process_time, "wall": time.perf_counter}


def episodes(count: int) -> list[dict[str, Any]]:
    """``count`` episodes' arguments, an equal share from each shipped scenario (seed = index),
    scenario by scenario."""
    names = list_scenarios()
    out = []
    for i in range(count):
        name = names[i * len(names) // count]
        env = CaptureEnv(name)
        env.reset(seed=i)
        arm, control, capture, plan = (
            env.description.arm,
            env.scenario.control,
            env.scenario.capture,
            env.plan,
        )
        out.append(
            {
                "scenario": name,
                "target_position": plan.trajectory.position,
                "target_velocity": plan.trajectory.velocity,
                "horizon": plan.end(),
                "travel_time": plan.travel_time if control.period_jitter else None,
                "shared": (
                    arm.home,
                    arm.joint_rate_limits,
                    arm.joint_lower,
                    arm.joint_upper,
                    env.description.capture_tolerance,
                ),
                "period": control.period,
                "envelope": {"hold": capture.hold, "v_max": capture.v_max},
            }
        )
    return out


def single(eps: list[dict[str, Any]]) -> list[PhysicalLimit]:
    return [
        physical_limit(
            e["target_position"],
            *e["shared"],
            horizon=e["horizon"],
            period=e["period"],
            travel_time=e["travel_time"],
            target_velocity=e["target_velocity"],
            **e["envelope"],
        )
        for e in eps
    ]


def batched(eps: list[dict[str, Any]], group: int) -> list[PhysicalLimit]:
    """`physical_limits` on groups of up to ``group`` consecutive episodes of one scenario."""
    chunks: list[list[dict[str, Any]]] = []
    for e in eps:
        if chunks and chunks[-1][0]["scenario"] == e["scenario"] and len(chunks[-1]) < group:
            chunks[-1].append(e)
        else:
            chunks.append([e])
    out: list[PhysicalLimit] = []
    for chunk in chunks:
        out += physical_limits(
            [e["target_position"] for e in chunk],
            *chunk[0]["shared"],
            horizons=[e["horizon"] for e in chunk],
            period=chunk[0]["period"],
            travel_times=[e["travel_time"] for e in chunk],
            target_velocities=[e["target_velocity"] for e in chunk],
            **chunk[0]["envelope"],
        )
    return out


def best_ms_per_episode(call: Callable[[], object], count: int, repeats: int, clock: str) -> float:
    timer, best = CLOCKS[clock], float("inf")
    for _ in range(repeats):
        start = timer()
        call()
        best = min(best, timer() - start)
    return 1e3 * best / count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=192)
    parser.add_argument("--groups", type=int, nargs="+", default=[16, 64])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="cpu")
    args = parser.parse_args()
    eps = episodes(args.episodes)
    reference = single(eps)
    for group in args.groups:
        got = batched(eps, group)
        assert [r.time for r in got] == [r.time for r in reference], f"G = {group} differs"
    print(f"{args.episodes} episodes from {len(list_scenarios())} scenarios, {args.clock} time")
    ms = best_ms_per_episode(lambda: single(eps), len(eps), args.repeats, args.clock)
    print(f"single      : {ms:7.3f} ms/episode")
    for group in args.groups:
        ms = best_ms_per_episode(
            lambda g=group: batched(eps, g), len(eps), args.repeats, args.clock
        )
        print(f"batch G={group:<4d}: {ms:7.3f} ms/episode")


if __name__ == "__main__":
    main()
