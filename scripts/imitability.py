"""How well can a policy network imitate a controller? Each teacher drives training episodes,
its actions on the states it visits are the labels, and a network of the shipped policies' shape
(16 -> 128 -> 128 -> 3, tanh; ``--hidden`` for others) is fitted to them; the table gives the
held-out mean squared error beside the labels' variance, and the labelling cost.

    python scripts/imitability.py                                   # paper: dls and both plans
    python scripts/imitability.py --teachers dls incremental_ik --steps 300

``planned_intercept`` keeps a plan between steps, so its action on a state depends on the states
before it; ``planned_intercept:fresh`` (`PlannedIntercept(keep_plans=False)`) plans from scratch at
every step, a function of the observation alone, the label DAgger needs on states the student
visits. Training seeds only (`CaptureSB3VecEnv`'s draws); the fit is the same for every teacher
(Adam 1e-3, minibatch 256, ``--epochs`` passes, an 80/20 split of the rows in a seeded order).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

import numpy as np

FRESH = ":fresh"


def make_teacher(name: str, scenario: str):
    """The controller ``name`` (a `TEACHERS` name, or ``planned_intercept:fresh``)."""
    from capture_bench.agents.planned_intercept import PlannedIntercept
    from capture_bench.agents.residual import TEACHERS, make_base
    from capture_bench.task.episode import describe_task
    from capture_bench.task.scenarios import load_scenario

    description = describe_task(load_scenario(scenario))
    if name == "planned_intercept" + FRESH:
        return PlannedIntercept(description, keep_plans=False)
    return make_base(name, description, TEACHERS)


def labels(name: str, scenario: str, envs: int, steps: int, seed: int):
    """(observations, actions, seconds): ``steps`` steps of ``envs`` training episodes driven by
    the teacher, its action on each state."""
    from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

    teacher = make_teacher(name, scenario)
    venv = CaptureSB3VecEnv(envs, scenario, seed=seed)
    xs, ys = [], []
    start = time.perf_counter()
    try:
        obs = venv.reset()
        for _ in range(steps):
            action = np.asarray(teacher.predict(obs)[0], dtype=np.float32)
            xs.append(np.array(obs, dtype=np.float32))
            ys.append(action)
            obs, _, _, _ = venv.step(action)
    finally:
        venv.close()
    return np.concatenate(xs), np.concatenate(ys), time.perf_counter() - start


def fit_error(
    x: np.ndarray, y: np.ndarray, epochs: int, seed: int, hidden: Sequence[int] = (128, 128)
) -> tuple[float, float]:
    """(train, held-out) mean squared error of a tanh network with ``hidden`` layers fitted to
    ``y`` on ``x``."""
    import torch

    torch.manual_seed(seed)
    order = np.random.default_rng(seed).permutation(len(x))
    cut = int(0.8 * len(x))
    xt, yt = torch.as_tensor(x), torch.as_tensor(y)
    train, test = torch.as_tensor(order[:cut]), torch.as_tensor(order[cut:])
    layers: list[torch.nn.Module] = []
    width = x.shape[1]
    for size in hidden:
        layers += [torch.nn.Linear(width, size), torch.nn.Tanh()]
        width = size
    net = torch.nn.Sequential(*layers, torch.nn.Linear(width, y.shape[1]))
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-3)
    for _ in range(epochs):
        shuffled = train[torch.randperm(len(train))]
        for lo in range(0, len(shuffled), 256):
            batch = shuffled[lo : lo + 256]
            loss = torch.mean((net(xt[batch]) - yt[batch]) ** 2)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    with torch.no_grad():
        return (
            float(torch.mean((net(xt[train]) - yt[train]) ** 2)),
            float(torch.mean((net(xt[test]) - yt[test]) ** 2)),
        )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper")
    parser.add_argument(
        "--teachers",
        nargs="+",
        default=["dls", "planned_intercept", "planned_intercept" + FRESH],
        help="TEACHERS names, planned_intercept, or planned_intercept:fresh",
    )
    parser.add_argument("--envs", type=int, default=32, help="training episodes at once")
    parser.add_argument("--steps", type=int, default=150, help="steps of the envs together")
    parser.add_argument("--epochs", type=int, default=300)
    parser.add_argument("--seed", type=int, default=12345, help="the training seeds' draw")
    parser.add_argument(
        "--hidden", type=int, nargs="+", default=[128, 128], help="the network's hidden layers"
    )
    args = parser.parse_args(argv)
    print(
        f"{args.scenario}: {args.envs} training episodes x {args.steps} steps per teacher; "
        f"fit {args.epochs} epochs, hidden layers {args.hidden}\n"
        "| teacher | rows | label variance | fit MSE (train) | fit MSE (held out) "
        "| ms per label |\n"
        "|---|---|---|---|---|---|"
    )
    for name in args.teachers:
        x, y, seconds = labels(name, args.scenario, args.envs, args.steps, args.seed)
        train, test = fit_error(x, y, args.epochs, 0, args.hidden)
        print(
            f"| {name} | {len(x)} | {float(np.mean(np.var(y, axis=0))):.3f} | {train:.4f} | "
            f"{test:.4f} | {1000 * seconds / len(x):.2f} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
