"""Reproduce Dong & Zhu (2016), section 4: a ``paper_eq20`` episode with the lambda_max controller.

Runs the paper's incremental IK controller (``capture_bench/agents/incremental_ik.py``) with the
vision estimate (photogrammetry -> EKF) on one published evaluation episode of the
``paper_eq20`` scenario (the ``paper`` scenario's targets and seeds under the paper's own capture
rule, eq. 20 as published: 1 mm, any speed, one instant) and draws the analogues of the paper's
figures:

* ``fig2_target_estimate.png`` — estimated vs true target position and velocity (global frame);
* ``fig3_joint_velocities.png`` — joint velocities dTheta/dt against their limits, and dTheta;
* ``fig4_positions.png`` — end-effector and target positions over time, and the 3-D paths.

It prints (and writes to ``summary.json``) the capture time under both capture tests: on the true
target position (``info["capture_time"]``) and on the estimate (``info["capture_time_estimated"]``),
next to the episode's physical limit. With ``--episodes N`` it also runs the first N published
seeds (no figures) and reports the spread.

This script is not an agent: reading ``env.unwrapped.true_target_position(t)`` to plot the truth is
allowed here. The controller itself sees only observations.

Usage::

    python scripts/reproduce_paper.py --out docs/figures
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from capture_bench.sensing.sources import SOURCES

PAPER_CAPTURE_TIME = 2.3  # s, "a capture is made at about 2.3 s" (section 4)


@dataclass
class Episode:
    """Per-step record of one episode (row k is the state after k steps; row 0 after reset)."""

    time: list[float] = field(default_factory=list)  # s
    estimate_position: list[np.ndarray] = field(default_factory=list)  # X^_T, global, m, (3,)
    estimate_velocity: list[np.ndarray] = field(default_factory=list)  # Xdot^_T, m/s, (3,)
    true_position: list[np.ndarray] = field(default_factory=list)  # X_T, global, m, (3,)
    ee_position: list[np.ndarray] = field(default_factory=list)  # X_E = f(Theta), m, (3,)
    joint_angles: list[np.ndarray] = field(default_factory=list)  # Theta, rad, (3,)
    commanded_increment: list[np.ndarray] = field(default_factory=list)  # dTheta asked, rad, (3,)
    info: dict[str, Any] = field(default_factory=dict)  # the final step's info

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v) for k, v in vars(self).items() if k != "info"}


def run_episode(
    scenario: str, seed: int, source: str, agent_name: str, record_truth: bool = True
) -> Episode:
    """Run one episode and record it (see `Episode`)."""
    import gymnasium

    import capture_bench  # noqa: F401  (registers the env IDs)
    from capture_bench.agents import make_agent
    from capture_bench.sim.kinematics import forward_kinematics
    from capture_bench.task.observation import decode_observation
    from capture_bench.task.scenarios import load_scenario

    env = gymnasium.make(load_scenario(scenario).env_id, observation_source=source)
    try:
        world = env.unwrapped
        t_s = world.description.control_period
        agent = make_agent(agent_name, env)
        agent.reset()
        observation, info = env.reset(seed=seed)
        ep = Episode()

        def record(obs: np.ndarray) -> None:
            o = decode_observation(obs, t_s)
            t = float(world.time)
            ep.time.append(t)
            ep.estimate_position.append(o.target_position)
            ep.estimate_velocity.append(o.target_velocity)
            ep.joint_angles.append(o.joint_angles)
            ep.ee_position.append(forward_kinematics(o.joint_angles))
            if record_truth:
                ep.true_position.append(np.asarray(world.true_target_position(t), float))

        record(observation)
        done = False
        while not done:
            action, _ = agent.predict(observation, deterministic=True)
            ep.commanded_increment.append(world.description.action_to_increment(action))
            observation, _, terminated, truncated, info = env.step(action)
            record(observation)
            done = terminated or truncated
        ep.info = dict(info)
        return ep
    finally:
        env.close()


def summarize(ep: Episode) -> dict[str, Any]:
    """Capture times (both tests), bound and outcome of an episode, JSON-ready."""
    info = ep.info

    def num(key: str) -> float | None:
        value = info.get(key)
        return None if value is None else float(value)

    gap = np.abs(np.asarray(ep.ee_position) - np.asarray(ep.estimate_position)).max(axis=1)
    return {
        "is_success": bool(info.get("is_success", False)),
        "failure": info.get("failure"),
        "capture_time": num("capture_time"),
        "capture_time_estimated": num("capture_time_estimated"),
        "physical_limit_time": num("physical_limit_time"),
        "episode_time": float(ep.time[-1]),
        # how close the end-effector came to the *estimate* (eq. 20 uses the max component), m
        "closest_to_estimate": float(gap.min()),
        "estimate_position_error_at_end": num("estimate_position_error"),
        "paper_capture_time": PAPER_CAPTURE_TIME,
    }


def plot_episode(ep: Episode, out: Path, title: str) -> list[Path]:
    """Write the three figures; return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from capture_bench.sim.kinematics import JOINT_RATE_LIMITS

    a = ep.arrays()
    t = a["time"]
    axes_names = ("x", "y", "z")
    colors = ("tab:blue", "tab:orange", "tab:green")
    true_vel = np.gradient(a["true_position"], t, axis=0)
    captured = ep.info.get("capture_time")
    paths = []

    def mark(ax: Any) -> None:
        if captured is not None:
            ax.axvline(captured, color="k", ls=":", lw=1, label=f"capture {captured:.2f} s")

    # Fig. 2: estimated vs true target position and velocity.
    fig, (ax_p, ax_v) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    for i, (name, c) in enumerate(zip(axes_names, colors)):
        ax_p.plot(t, a["true_position"][:, i], color=c, lw=2, alpha=0.4, label=f"true {name}_T")
        ax_p.plot(t, a["estimate_position"][:, i], color=c, lw=1, ls="--", label=f"EKF {name}_T")
        ax_v.plot(t, true_vel[:, i], color=c, lw=2, alpha=0.4, label=f"true d{name}_T/dt")
        ax_v.plot(
            t, a["estimate_velocity"][:, i], color=c, lw=1, ls="--", label=f"EKF d{name}_T/dt"
        )
    ax_p.set_ylabel("target position [m]")
    ax_v.set_ylabel("target velocity [m/s]")
    ax_v.set_xlabel("time [s]")
    for ax in (ax_p, ax_v):
        mark(ax)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=4)
    ax_p.set_title(f"Fig. 2 analogue: estimated vs true target state\n({title})")
    paths.append(_save(fig, out / "fig2_target_estimate.png"))

    # Fig. 3: joint velocities against their limits (left) and the increments dTheta (right).
    dt = np.diff(t)
    rates = np.diff(a["joint_angles"], axis=0) / dt[:, None]  # achieved, rad/s
    commanded = a["commanded_increment"] / dt[:, None]  # dTheta / t_actual, rad/s
    fig, axes = plt.subplots(3, 2, figsize=(11, 8), sharex=True)
    for i in range(3):
        ax, ax_inc = axes[i]
        lim = JOINT_RATE_LIMITS[i]
        ax.stairs(
            rates[:, i],
            t,
            baseline=None,
            color=colors[i],
            lw=1.5,
            label=f"dtheta{i + 1}/dt achieved",
        )
        ax.plot(t[1:] - dt / 2, commanded[:, i], "k.", ms=3, label="dTheta/t_s commanded")
        ax.axhline(lim, color="r", ls="--", lw=1, label=f"+-limit {lim} rad/s")
        ax.axhline(-lim, color="r", ls="--", lw=1)
        ax.set_ylabel(f"joint {i + 1} rate [rad/s]")
        increments = np.degrees(np.diff(a["joint_angles"][:, i]))
        ax_inc.stairs(
            increments, t, baseline=None, color=colors[i], lw=1.5, label=f"dtheta{i + 1} per step"
        )
        ax_inc.axhline(np.degrees(lim * dt.mean()), color="r", ls="--", lw=1, label="limit x t_s")
        ax_inc.axhline(-np.degrees(lim * dt.mean()), color="r", ls="--", lw=1)
        ax_inc.set_ylabel(f"dTheta{i + 1} [deg]")
        for axis in (ax, ax_inc):
            mark(axis)
            axis.grid(alpha=0.3)
            axis.legend(fontsize=7, loc="lower left")
    axes[0, 0].set_title("joint velocities vs their limits")
    axes[0, 1].set_title("incremental control input dTheta (eq. 19)")
    fig.suptitle(f"Fig. 3 analogue ({title})")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    paths.append(_save(fig, out / "fig3_joint_velocities.png"))

    # Fig. 4: positions of the target (lines) and the end-effector (circles).
    fig = plt.figure(figsize=(12, 5))
    ax = fig.add_subplot(1, 2, 1)
    for i, (name, c) in enumerate(zip(axes_names, colors)):
        ax.plot(t, a["true_position"][:, i], color=c, lw=1.5, label=f"target {name}_T")
        ax.plot(
            t[::2],
            a["ee_position"][::2, i],
            "o",
            color=c,
            mfc="none",
            ms=4,
            label=f"end-effector {name}_E",
        )
    mark(ax)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position, global frame [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(f"Fig. 4 analogue: target (lines), end-effector (circles)\n({title})")
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    ax3.plot(*a["true_position"].T, "k-", lw=2, label="target (true)")
    ax3.plot(*a["estimate_position"].T, "b--", lw=0.8, label="target (EKF)")
    ax3.plot(*a["ee_position"].T, "o-", color="tab:red", ms=2, lw=0.8, label="end-effector")
    ax3.scatter(*a["ee_position"][0], color="tab:red", s=30, marker="s", label="home")
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    ax3.legend(fontsize=7)
    paths.append(_save(fig, out / "fig4_positions.png"))
    return paths


def _save(fig: Any, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/figures"), help="figure folder")
    parser.add_argument(
        "--scenario",
        default="paper_eq20",
        help="scenario name (default: paper_eq20, the paper's eq. 20 on paper's targets)",
    )
    parser.add_argument(
        "--agent", default="incremental_ik", help="agent name (default: incremental_ik)"
    )
    parser.add_argument(
        "--source",
        default="ekf",
        choices=SOURCES,
        help="observation source (default: ekf, as in the paper)",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=None,
        help="episode seed (default: the scenario's first evaluation seed)",
    )
    parser.add_argument(
        "--episodes",
        type=int,
        default=0,
        help="also run the first N evaluation seeds and report the spread",
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the reproduction; returns the exit status."""
    from capture_bench.task.scenarios import load_scenario

    args = parse_args(argv)
    scenario = load_scenario(args.scenario)
    seed = scenario.evaluation_seeds[0] if args.seed is None else args.seed
    args.out.mkdir(parents=True, exist_ok=True)
    ep = run_episode(args.scenario, seed, args.source, args.agent)
    summary = {
        "scenario": args.scenario,
        "agent": args.agent,
        "source": args.source,
        "seed": seed,
        **summarize(ep),
    }
    title = f"{args.scenario}, seed {seed}, {args.agent}, {args.source}; paper: capture at ~2.3 s"
    summary["figures"] = [str(p) for p in plot_episode(ep, args.out, title)]
    if args.episodes > 0:
        rows = []
        for s in scenario.evaluation_seeds[: args.episodes]:
            rows.append(
                {
                    "seed": s,
                    **summarize(
                        run_episode(args.scenario, s, args.source, args.agent, record_truth=False)
                    ),
                }
            )
        summary["seeds"] = rows
        summary["spread"] = spread(rows)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({k: v for k, v in summary.items() if k != "seeds"}, indent=2))
    return 0


def spread(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Capture rate and capture-time quartiles over several episodes, both capture tests."""
    result: dict[str, Any] = {"episodes": len(rows), "captured": sum(r["is_success"] for r in rows)}
    for key in ("capture_time", "capture_time_estimated", "physical_limit_time"):
        values = np.array([r[key] for r in rows if r[key] is not None and np.isfinite(r[key])])
        if values.size:
            q = np.percentile(values, [25, 50, 75])
            result[key] = {"n": int(values.size), "q25": q[0], "median": q[1], "q75": q[2]}
    ratios = [
        r["capture_time"] / r["physical_limit_time"]
        for r in rows
        if r["capture_time"] is not None and r["physical_limit_time"]
    ]
    if ratios:
        result["ratio_to_limit_median"] = float(np.median(ratios))
    return result


if __name__ == "__main__":
    # Let ``python scripts/reproduce_paper.py`` work from a checkout without installing.
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    sys.exit(main())
