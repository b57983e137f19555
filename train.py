"""Train a Stable-Baselines3 policy on a capture-bench scenario.

    python train.py --algo ppo --scenario paper
    python train.py --algo sac --scenario paper --total-timesteps 200000 --seed 7
    python train.py --resume runs/paper-ppo-0 --total-timesteps 4000000
    tensorboard --logdir runs/paper-ppo-0/tb

Hyper-parameters come from ``configs/algos/<algo>.yaml`` (or ``--config``), validated by
:mod:`capture_bench.training`. A run directory holds ``config.json`` (everything needed to resume),
``tb/`` (TensorBoard), ``checkpoints/`` (model, replay buffer and VecNormalize statistics, each
written to a temporary file and renamed, so an interrupted save never leaves a corrupt checkpoint),
and at the end ``model.zip`` + ``metadata.json``, the format :mod:`agents.sb3_policy` loads. Ctrl-C
saves a checkpoint and exits with status 130. A user's mistake is one line on stderr and exit 2.
"""

from __future__ import annotations

import json
import re
import sys
import time
from pathlib import Path
from typing import Any

from capture_bench.scenarios import ConfigError, load_scenario
from capture_bench.training import (
    OFF_POLICY,
    RESUMABLE_OPTIONS,
    TrainConfig,
    TrainingSeeds,
    atomic_write,
    check_training_seed,
    load_hyperparameters,
    parse_args,
    sb3_kwargs,
    validate_hyperparameters,
)

CHECKPOINT = re.compile(r"model_(\d+)_steps\.zip$")


def main(argv: list[str] | None = None) -> int:
    """Run ``train.py`` with ``argv`` (default: ``sys.argv[1:]``); return the exit status."""
    try:
        config, given = parse_args(argv)
        config, hp, run_dir, checkpoint = prepare(config, given)
    except ConfigError as exc:
        print(f"train.py: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # argparse: --help (0) or a bad option (2, already printed)
        return int(exc.code or 0)
    try:
        return train(config, hp, run_dir, checkpoint)
    except KeyboardInterrupt:  # before learning started (during imports or env start-up)
        print("\ninterrupted before training started; nothing to save", file=sys.stderr)
        return 130


def prepare(config: TrainConfig, given: set[str]) -> tuple[TrainConfig, dict, Path, Path | None]:
    """Resolve the options: the run's config, hyper-parameters, directory and resume checkpoint."""
    if config.resume is not None:
        run_dir = Path(config.resume)
        saved = run_dir / "config.json"
        if not saved.is_file():
            raise ConfigError(f"{run_dir}: not a run directory (no config.json) to resume")
        extra = sorted(given - set(RESUMABLE_OPTIONS) - {"resume"})
        if extra:
            raise ConfigError(
                f"--resume reuses the run's saved config; only --total-timesteps, --vec-env and "
                f"--device may be given with it, not --{extra[0].replace('_', '-')}"
            )
        data = json.loads(saved.read_text())
        old = TrainConfig(**data["config"])
        config = TrainConfig(
            **{**data["config"], **{k: getattr(config, k) for k in given if k != "resume"}}
        )
        hp = validate_hyperparameters(data["hyperparameters"], old.algo, str(saved))
        if config.total_timesteps is not None:
            hp["total_timesteps"] = config.total_timesteps
        checkpoint = latest_checkpoint(run_dir, old.algo in OFF_POLICY, hp["normalize"])
        if checkpoint is None:
            raise ConfigError(f"{run_dir}: no complete checkpoint to resume from")
        return config, hp, run_dir, checkpoint

    config.algo = config.algo.lower()
    hp, _ = load_hyperparameters(config.algo, config.config)
    scenario = load_scenario(config.scenario)
    if config.seed is None:
        config.seed = scenario.training_seeds.start
    check_training_seed(config.seed, scenario)
    for key in ("total_timesteps", "n_envs"):
        if getattr(config, key) is not None:
            if getattr(config, key) < 1:
                raise ConfigError(
                    f"--{key.replace('_', '-')} must be >= 1, got {getattr(config, key)}"
                )
            hp[key] = getattr(config, key)
    config.total_timesteps, config.n_envs = hp["total_timesteps"], hp["n_envs"]
    config.observation_source = config.observation_source or scenario.estimator.source
    run_dir = Path(config.run_dir or f"runs/{scenario.name}-{config.algo}-{config.seed}")
    if (run_dir / "config.json").exists():
        raise ConfigError(
            f"{run_dir}: already holds a run; use --resume {run_dir} or another --run-dir"
        )
    config.run_dir = str(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    payload = {"config": vars(config) | {"resume": None}, "hyperparameters": hp}
    atomic_write(run_dir / "config.json", json.dumps(payload, indent=2).encode())
    return config, hp, run_dir, None


def latest_checkpoint(run_dir: Path, replay_buffer: bool, normalize: bool) -> Path | None:
    """The newest checkpoint whose companion files (replay buffer, VecNormalize) all exist."""
    found = []
    for path in (run_dir / "checkpoints").glob("model_*_steps.zip"):
        match = CHECKPOINT.search(path.name)
        if match is None:
            continue
        steps = match.group(1)
        needs = [f"replay_buffer_{steps}_steps.pkl"] * replay_buffer
        needs += [f"vecnormalize_{steps}_steps.pkl"] * normalize
        if all((path.parent / name).is_file() for name in needs):
            found.append((int(steps), path))
    return max(found)[1] if found else None


def make_env(config: TrainConfig, reward: str, rank: int, subprocess: bool) -> Any:
    """A thunk building environment ``rank``: CaptureEnv with training seeds only."""

    def thunk() -> Any:
        if subprocess:  # Ctrl-C goes to the main process only; it saves and closes the workers
            import signal

            signal.signal(signal.SIGINT, signal.SIG_IGN)
        from capture_bench.env import CaptureEnv

        scenario = load_scenario(config.scenario)
        env = CaptureEnv(scenario, observation_source=config.observation_source, reward=reward)
        return TrainingSeeds(env, scenario, seed=(config.seed or 0) * 1000 + rank)

    return thunk


def train(config: TrainConfig, hp: dict, run_dir: Path, checkpoint: Path | None) -> int:
    """Build the envs and the model (or load the checkpoint), learn, and save the result."""
    import stable_baselines3
    from stable_baselines3.common.vec_env import (
        DummyVecEnv,
        SubprocVecEnv,
        VecMonitor,
        VecNormalize,
    )

    from capture_bench.training_callbacks import Checkpointer, Progress

    algo = config.algo
    subprocess = config.vec_env == "subproc"
    fns = [make_env(config, hp["reward"], i, subprocess) for i in range(config.n_envs or 1)]
    venv: Any = SubprocVecEnv(fns) if subprocess else DummyVecEnv(fns)
    venv = VecMonitor(venv)
    stats_name = "vecnormalize_{}_steps.pkl"
    if hp["normalize"] and checkpoint is not None:
        steps = CHECKPOINT.search(checkpoint.name).group(1)  # type: ignore[union-attr]
        venv = VecNormalize.load(str(checkpoint.parent / stats_name.format(steps)), venv)
    elif hp["normalize"]:
        venv = VecNormalize(venv, gamma=hp.get("gamma", 0.99))
    algorithm = getattr(stable_baselines3, algo.upper())
    tb = str(run_dir / "tb")
    if checkpoint is None:
        seed_note = f"seed {config.seed}"
        model = algorithm(
            hp["policy"], venv, seed=config.seed, device=config.device, tensorboard_log=tb,
            **sb3_kwargs(hp, algo),
        )  # fmt: skip
    else:
        model = algorithm.load(str(checkpoint), env=venv, device=config.device, tensorboard_log=tb)
        if algo in OFF_POLICY:
            model.load_replay_buffer(str(checkpoint).replace("model_", "replay_buffer_")[:-4])
        model.set_random_seed((config.seed or 0) + model.num_timesteps)  # fresh episode draws
        seed_note = f"resuming {checkpoint.name}"
    target = hp["total_timesteps"]
    print(
        f"training {algo.upper()} on {config.scenario} ({config.observation_source}), "
        f"{config.n_envs} {config.vec_env} envs, {seed_note}, {target} steps -> {run_dir}"
    )
    print(f"TensorBoard: tensorboard --logdir {tb}")
    checkpointer = Checkpointer(run_dir / "checkpoints", hp["checkpoint_freq"], algo in OFF_POLICY)
    progress = Progress(config, hp, target)
    start = time.perf_counter()
    status = 0
    try:
        model.learn(
            total_timesteps=max(target - model.num_timesteps, 0),
            callback=[checkpointer, progress],
            reset_num_timesteps=checkpoint is None,
            tb_log_name="run",
        )
    except KeyboardInterrupt:
        status = 130
        path = checkpointer.save(model)
        add_wall_time(run_dir, time.perf_counter() - start)
        print(f"\ninterrupted at {model.num_timesteps} steps; checkpoint {path}; "
              f"continue with: python train.py --resume {run_dir}")  # fmt: skip
    finally:
        progress.close()
        close_envs(venv, interrupted=status != 0)
    if status:
        return status
    checkpointer.save(model)
    wall = time.perf_counter() - start
    total_wall = add_wall_time(run_dir, wall)
    save_final(model, config, hp, run_dir, total_wall)
    print(f"done: {model.num_timesteps} steps in {wall:.0f} s; model: {run_dir / 'model.zip'}")
    return 0


def close_envs(venv: Any, interrupted: bool) -> None:
    """Close the vectorised envs; after Ctrl-C, terminate subprocess workers instead.

    Ctrl-C can land while the main process waits on the workers' pipes; SB3's graceful close
    would then wait for replies already consumed, forever (seen on the 16-env device run).
    """
    base = venv.unwrapped
    if interrupted and hasattr(base, "processes"):
        for process in base.processes:
            process.terminate()
        for process in base.processes:
            process.join(timeout=5)
        base.closed = True
        return
    venv.close()


def add_wall_time(run_dir: Path, seconds: float) -> float:
    """Add a session's training time to ``run_dir/wall_time.json``; return the total, s."""
    path = run_dir / "wall_time.json"
    total = json.loads(path.read_text())["wall_time_s"] if path.is_file() else 0.0
    total += seconds
    atomic_write(path, json.dumps({"wall_time_s": round(total, 1)}).encode())
    return total


def save_final(
    model: Any,
    config: TrainConfig,
    hp: dict,
    run_dir: Path,
    total_wall: float,
) -> None:
    """Write the policy in the safe form (``policy.pt`` + declared ``metadata.json``, loaded
    without unpickling: :mod:`agents.policy_file`), and SB3's own ``model.zip`` (+
    ``vecnormalize.pkl``) for SB3 users who trust the run."""
    from agents.policy_file import ObservationNormalizer, save_policy
    from capture_bench.evaluation.provenance import git_state, package_versions

    atomic_write(run_dir / "model.zip", writer=model.save)
    env = model.get_vec_normalize_env()
    if env is not None:
        atomic_write(run_dir / "vecnormalize.pkl", writer=env.save)
    scenario = load_scenario(config.scenario)
    metadata = {
        "algorithm": config.algo.upper(),
        "scenario": scenario.name,
        "env_id": scenario.env_id,
        "model": "model.zip",
        "observation_source": config.observation_source,
        "reward": hp["reward"],
        "vecnormalize": "vecnormalize.pkl" if env is not None else None,
        "total_timesteps": int(model.num_timesteps),
        "seed": config.seed,
        "n_envs": config.n_envs,
        "device": str(model.device),
        "wall_time_s": round(total_wall, 1),  # training time over all sessions of the run
        "steps_per_second": round(model.num_timesteps / total_wall, 1) if total_wall else None,
        "git": git_state(),
        "packages": package_versions(),
        "hyperparameters": hp,
        "command": "python train.py " + " ".join(
            f"--{k.replace('_', '-')} {v}" for k, v in vars(config).items()
            if v is not None and k not in ("resume", "config", "run_dir")
        ),
    }  # fmt: skip
    normalizer = None if env is None else ObservationNormalizer.from_vecnormalize(env)
    save_policy(run_dir, config.algo, model.policy, normalizer, extra=metadata)


if __name__ == "__main__":
    sys.exit(main())
