"""One training run, what ``train.py`` does: check every option before any work, build the envs
and the SB3 model (`capture_bench.training.common.build`; or restore the run's newest checkpoint),
learn, and save the policy in the safe form. ``train.py``'s command
(`capture_bench.training.train.command`) is `main`; the sweep's tasks and ``curves --train``
train their runs with it, and the sweep checks its runs' options with `prepare`.

Hyper-parameters come from ``configs/algos/<algo>.yaml``, with ``--config`` (a file that may
set a few keys), ``--set`` and the options layered over it, validated by
`capture_bench.training.config.hyperparameters`. A run goes to ``--run-dir``, by default
``runs/<scenario>-<algo>-<seed>`` or, where that is taken, the first free ``..._2``, ``..._3``;
an existing run is never written into but by ``--resume``. A run directory holds
``config.json`` (everything needed to resume), ``tb/`` (TensorBoard), ``checkpoints/step_<N>/``
(`capture_bench.training.common.checkpoint`: parameters, optimiser state, counters, replay buffer
and VecNormalize statistics, written under a temporary name and renamed, and read back without
unpickling anything), ``best/`` (the policy of the best periodic validation so far, in the safe
form: `capture_bench.training.common.policy_export`), and at the end the policy in the safe form
``policy.pt`` + ``metadata.json`` (`capture_bench.agents.policy_file`), beside SB3's own
``model.zip``.
Ctrl-C (SIGINT) or SIGTERM saves a checkpoint and exits with status 130 or 143. A user's mistake
is one line on stderr and exit 2, found before any environment is built. SB3 trains in whole
rollouts of ``n_steps x n_envs`` steps (PPO, A2C) or ``train_freq x n_envs`` (off-policy): a
budget that is not a multiple is rounded up, with a note saying so, and the progress counts to the
rounded total.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from capture_bench.argparsing import program
from capture_bench.files import atomic_write, check_writable
from capture_bench.interrupts import exit_status, sigterm_as_interrupt
from capture_bench.sensing.sources import ENV_OBSERVATIONS, PIXELS
from capture_bench.task.scenarios import ConfigError
from capture_bench.training.common.build import (
    build_model,
    build_venv,
    check_curricula,
    check_imitation,
    check_observation,
    check_shaping,
    close_envs,
    curriculum_callbacks,
    fill_curriculum_steps,
    mixture_curricula,
    shares_of,
)
from capture_bench.training.common.checkpoint import (
    CheckpointError,
    list_checkpoints,
    read_checkpoint,
    restore,
)
from capture_bench.training.common.imitation_progress import RoundStore
from capture_bench.training.common.mixture import (
    is_mixture,
    mixture_name,
    mixture_scenarios,
)
from capture_bench.training.common.policy_export import IMITATION_FILE
from capture_bench.training.common.run_lock import RunLock
from capture_bench.training.config.hyperparameters import (
    ALGORITHMS,
    OFF_POLICY,
    TRAINING_KEYS,
    algorithm_class,
)
from capture_bench.training.config.options import (
    FLAGS,
    RESUMABLE_OPTIONS,
    TrainConfig,
    parse_args,
)
from capture_bench.training.config.settings import TrainingSettings, resolve_settings
from capture_bench.training.seeds import check_training_seed

#: Memory one training environment holds (a pybullet world, the estimator, the recordings):
#: above what a CaptureEnv was measured to hold, for a margin.
ENV_MEMORY_BYTES = 40 * 2**20
#: The same for one sub-env of the batched env, which shares one pybullet world: above what a
#: sub-env was measured to add beyond the env itself (16 against 128 sub-envs, 250 steps).
BATCHED_ENV_MEMORY_BYTES = 2 * 2**20
#: Share of the available memory a run may take: its environments (the count check), and its
#: environments with its buffers, networks and update batch (the estimate,
#: `memory_estimate`).
MEMORY_SHARE = 0.8


def main(argv: list[str] | None = None) -> int:
    """Run ``train.py`` with ``argv`` (default: ``sys.argv[1:]``); return the exit status.

    The run directory is locked for the run's whole life (`RunLock`). A new run that fails before
    its first checkpoint and before a complete round of its imitation (an interrupt while the
    envs start, an error) leaves its directory as it found it, so the same command can be run
    again."""
    with RunLock() as lock:
        try:
            config, given = parse_args(argv)
            config, settings, run_dir, checkpoint = prepare(config, given, lock)
        except (ConfigError, CheckpointError, OSError) as exc:  # OSError: a path unreadable
            return _error(exc)
        except SystemExit as exc:  # argparse: --help (0) or a bad option (2, already printed)
            return int(exc.code or 0)
        new = checkpoint is None and lock.found is not None  # a new run (not a resume)
        with sigterm_as_interrupt():
            try:
                return train(config, settings, run_dir, checkpoint)
            except KeyboardInterrupt as exc:  # before learning started (imports, env start-up)
                _discard_unstarted(lock, run_dir, new)
                print("\ninterrupted before training started; nothing to save", file=sys.stderr)
                return exit_status(exc)
            except CheckpointError as exc:  # the newest checkpoint does not fit the run's model
                return _error(exc)
            except MemoryError:  # the estimate (_check_memory) fell short of what SB3 allocated
                _discard_unstarted(lock, run_dir, new)
                return _error(
                    f"out of memory ({_size(_memory_available() or 0)} available); choose "
                    "smaller n_envs, n_steps, buffer_size, batch_size or policy_kwargs.net_arch"
                )
            except BaseException:
                _discard_unstarted(lock, run_dir, new)
                raise


def _error(exc: object) -> int:
    """Print train.py's one-line error; return the exit status of bad input, 2."""
    print(f"{program('train.py')}: error: {' '.join(str(exc).split())}", file=sys.stderr)
    return 2


def _discard_unstarted(lock: RunLock, run_dir: Path, new: bool) -> None:
    """Remove what a new run wrote into ``run_dir`` where it has nothing to resume from: no
    checkpoint and no complete round of its imitation (`discard`)."""
    if new and not list_checkpoints(run_dir / "checkpoints"):
        if not RoundStore.of_run(run_dir).rounds_done():
            lock.discard(run_dir)


def _read_run_config(run_dir: Path) -> tuple[dict, TrainConfig]:
    """The saved ``config.json`` of a run, validated: (its mapping, its options)."""
    saved = run_dir / "config.json"
    if not saved.is_file():
        raise ConfigError(f"{run_dir}: not a run directory (no config.json) to resume")
    try:
        data = json.loads(saved.read_text())
    except (OSError, ValueError) as exc:
        reason = " ".join(str(exc).split())
        raise ConfigError(f"{saved}: unreadable ({reason}); it is written by train.py") from None
    if not (
        isinstance(data, dict)
        and isinstance(data.get("config"), dict)
        and isinstance(data.get("hyperparameters"), dict)
    ):
        raise ConfigError(f"{saved}: expected keys 'config' and 'hyperparameters' (mappings)")
    try:
        old = TrainConfig(**data["config"])
    except TypeError as exc:
        raise ConfigError(
            f"{saved}: key 'config' does not hold train.py's options ({exc})"
        ) from None
    if not isinstance(old.algo, str) or old.algo not in ALGORITHMS:
        raise ConfigError(
            f"{saved}: key 'config.algo' is {old.algo!r}; valid: {', '.join(ALGORITHMS)}"
        )
    for key in ("seed", "n_envs"):
        value = getattr(old, key)
        if (
            not isinstance(value, int)
            or isinstance(value, bool)
            or value < (1 if key == "n_envs" else 0)
        ):
            raise ConfigError(f"{saved}: key 'config.{key}' is {value!r}; valid: a whole number")
    if old.observation_source is not None and old.observation_source not in ENV_OBSERVATIONS:
        raise ConfigError(  # None: a mixture, where each scenario keeps its own estimate
            f"{saved}: key 'config.observation_source' is {old.observation_source!r}; "
            f"valid: {', '.join(ENV_OBSERVATIONS)}, or null for a mixture"
        )
    try:
        mixture_scenarios(str(old.scenario))  # one scenario, or a mixture ("all", "a,b")
    except ConfigError as exc:
        raise ConfigError(f"{saved}: key 'config.scenario': {exc}") from None
    return data, old


def prepare(
    config: TrainConfig, given: set[str], lock: RunLock | None = None
) -> tuple[TrainConfig, TrainingSettings, Path, Path | None]:
    """Resolve and check the options before any work: the run's config, hyper-parameters,
    directory and resume checkpoint. Raises [`ConfigError`][capture_bench.ConfigError] naming what
    is wrong.

    The run directory is locked with ``lock``, which the caller releases when the run ends
    (without one, the lock is released on return); a directory another train.py holds is refused.
    Nothing is written before every check has passed."""
    if lock is not None:
        return _prepare(config, given, lock)
    with RunLock() as own:
        return _prepare(config, given, own)


def _prepare(
    config: TrainConfig, given: set[str], lock: RunLock
) -> tuple[TrainConfig, TrainingSettings, Path, Path | None]:
    _check_device(config.device)
    if config.resume is not None:
        run_dir = Path(config.resume)
        data, old = _read_run_config(run_dir)
        lock.acquire(run_dir)
        extra = sorted(given - set(RESUMABLE_OPTIONS) - {"resume"})
        if extra:
            flag = FLAGS.get(extra[0], "--" + extra[0].replace("_", "-"))
            raise ConfigError(
                f"--resume reuses the run's saved config; only --total-timesteps, --vec-env and "
                f"--device may be given with it, not {flag}"
            )
        config = TrainConfig(
            **{**data["config"], **{k: getattr(config, k) for k in given if k != "resume"}}
        )
        # the run is where it is now: a run moved (or copied to another machine) writes its
        # validations, best/ and final policy there, not where config.json says it started
        config.run_dir = str(run_dir)
        settings = TrainingSettings.from_mapping(
            data["hyperparameters"], old.algo, str(run_dir / "config.json")
        )
        if config.total_timesteps is not None:
            settings = dataclasses.replace(settings, total_timesteps=config.total_timesteps)
            _check_option_bounds(settings.n_envs, settings.total_timesteps)
        if is_mixture(config.scenario):  # e.g. --vec-env dummy: a mixture trains batched
            _check_mixture(config, settings, len(mixture_scenarios(config.scenario)))
        _check_memory(config, settings, resume=True)
        found = list_checkpoints(run_dir / "checkpoints")
        imitated = (run_dir / IMITATION_FILE).is_file()
        kept = RoundStore.of_run(run_dir).rounds_done()
        if not found and settings.imitate is not None and (not imitated or kept):
            # stopped during its imitation, or after it and before its first checkpoint: it goes
            # on from its last complete round (all of them: the imitated policy back)
            check_writable(run_dir, "--resume")
            return config, settings, run_dir, None
        if not found:
            raise ConfigError(
                f"{run_dir}: no complete checkpoint (checkpoints/step_<N>/) to resume"
            )
        done, checkpoint = found[-1]
        read_checkpoint(checkpoint)  # a corrupt newest checkpoint is an error here, not later
        if settings.total_timesteps <= done and "total_timesteps" in given:
            raise ConfigError(
                f"--total-timesteps {settings.total_timesteps} is not more than the {done} steps "
                f"{run_dir} has done; pass the new total, above {done}, to train it further"
            )
        if settings.total_timesteps <= done:
            raise ConfigError(
                f"{run_dir}: the run is finished: it has done {done} steps of its total_timesteps "
                f"{settings.total_timesteps}; to train it further, pass a new total above {done}: "
                f"python train.py --resume {run_dir} --total-timesteps <steps>"
            )
        check_writable(run_dir, "--resume")
        note_rounding(settings, done)
        return config, settings, run_dir, checkpoint

    config.algo = config.algo.lower()
    scenarios = mixture_scenarios(config.scenario)  # one, or a mixture (``all``, a,b,c)
    scenario = scenarios[0]
    mixed = is_mixture(config.scenario)
    for key in ("total_timesteps", "n_envs"):
        if getattr(config, key) is not None and getattr(config, key) < 1:
            raise ConfigError(f"--{key.replace('_', '-')} must be >= 1, got {getattr(config, key)}")
    settings, _, origin = resolve_settings(  # a mixture reads no scenario section
        config.algo, None if mixed else scenario, config.config, config.overrides or ()
    )
    algorithm_class(config.algo)  # its package is installed (sb3-contrib for TQC)
    if config.seed is None:
        config.seed = scenario.training_seeds.start
    for each in scenarios:
        check_training_seed(config.seed, each)
    options = ("total_timesteps", "n_envs", "reward")  # the options win over the file
    chosen = {key: getattr(config, key) for key in options if getattr(config, key) is not None}
    settings = dataclasses.replace(settings, **chosen)
    check_shaping(settings.reward, settings.gamma)
    settings = fill_curriculum_steps(settings)  # after the options: half the budget they set
    config.total_timesteps, config.n_envs = settings.total_timesteps, settings.n_envs
    _check_env_count(config.n_envs, config.vec_env)
    _check_option_bounds(settings.n_envs, settings.total_timesteps)
    if mixed:
        _check_mixture(config, settings, len(scenarios))
    elif settings.mixture_weights is not None:
        raise ConfigError(
            f"key 'mixture_weights' splits a mixture's sub-envs between its scenarios; train on "
            f"a mixture (--scenario all, or a,b,c), or drop it for {scenario.name}"
        )
    else:
        config.observation_source = config.observation_source or scenario.estimator.source
        check_curricula(settings, scenario)
    check_observation(config, settings)
    check_imitation(config, settings, [s.name for s in scenarios])
    kind = config.algo if settings.residual == "none" else f"{config.algo}-residual"
    name = mixture_name(config.scenario) if mixed else scenario.name
    if config.run_dir is None:
        default = Path(f"runs/{name}-{kind}-{config.seed}")
        run_dir = free_run_dir(default)
        if run_dir != default:
            print(f"note: {default} is taken (--resume {default} continues that run); this run "
                  f"goes to {run_dir} (--run-dir chooses another)")  # fmt: skip
    else:
        run_dir = Path(config.run_dir)
    _check_new_run_dir(run_dir)
    check_writable(run_dir, "--run-dir")
    _check_memory(config, settings)
    config.run_dir = str(run_dir)
    created = not run_dir.exists()
    run_dir.mkdir(parents=True, exist_ok=True)
    try:
        lock.acquire(run_dir)
        _check_new_run_dir(run_dir)  # again, locked: another train.py may have started it
    except ConfigError:
        if created:  # left empty, as it was not there
            with contextlib.suppress(OSError):
                run_dir.rmdir()
        raise
    lock.found = frozenset(entry.name for entry in run_dir.iterdir())
    lock.created = created
    note_rounding(settings)
    from capture_bench.provenance import git_state

    payload = {
        "config": vars(config) | {"resume": None},
        "hyperparameters": settings.to_mapping(),
        "origin": origin,
        "git": git_state(),  # the code the run starts from (metadata.json's "git")
    }
    atomic_write(run_dir / "hyperparameters.yaml", resolved_yaml(config, settings, origin).encode())
    atomic_write(run_dir / "config.json", json.dumps(payload, indent=2).encode())
    return config, settings, run_dir, None


def _check_new_run_dir(run_dir: Path) -> None:
    """A new run goes only where no run is."""
    if (run_dir / "config.json").exists():
        raise ConfigError(
            f"{run_dir}: already holds a run; use --resume {run_dir} or another --run-dir"
        )


def free_run_dir(default: Path) -> Path:
    """``default``, or else the first of ``default_2``, ``default_3``, ... that does not exist
    (or is an empty folder), as the RL Zoo numbers its runs: a new run never mixes with one."""
    candidate, number = default, 1
    while candidate.exists() and not (candidate.is_dir() and not any(candidate.iterdir())):
        number += 1
        candidate = default.with_name(f"{default.name}_{number}")
    return candidate


def _check_mixture(config: TrainConfig, settings: TrainingSettings, count: int) -> None:
    """What a mixture of ``count`` scenarios needs: the batched env, sub-envs for every scenario
    (`mixture_shares`), and no setting that depends on one
    scenario's task."""
    if config.vec_env != "batched":
        raise ConfigError(
            f"--scenario {config.scenario}: a mixture trains on --vec-env batched, not "
            f"{config.vec_env}"
        )
    try:
        shares_of(config, settings)
    except ConfigError as exc:
        raise ConfigError(f"--scenario {config.scenario}: {exc}") from None
    if settings.residual != "none":
        raise ConfigError(
            f"--scenario {config.scenario}: residual depends on one scenario's task; train it "
            "on a single scenario"
        )
    scenarios = mixture_scenarios(config.scenario)
    found = {name for name, _ in mixture_curricula(settings, scenarios, [1] * count)}
    for key, name, rule in (
        ("curriculum_hold", "HoldCurriculum", "a longer capture.hold"),
        ("curriculum_tolerance", "ToleranceCurriculum", "a smaller capture tolerance"),
    ):
        start = getattr(settings, key)
        if start is not None and name not in found:
            raise ConfigError(
                f"--scenario {config.scenario}: {key} {start:g} moves on no scenario of the "
                f"mixture (none asks {rule}); leave it out, or start it on the easy side of one "
                "(e.g. curriculum_hold=0 with grasp in the mixture)"
            )


def imitate(
    config: TrainConfig, settings: TrainingSettings, model: Any, venv: Any, progress: Any
) -> dict[str, Any]:
    """DAgger from ``settings.imitate`` on the run's training envs (``venv`` inside ``VecMonitor``,
    so the imitation's episodes stay out of the algorithm's statistics), the policy validated
    after each round where the run validates (``eval_freq``; ``progress``'s validation, nothing
    logged): `capture_bench.training.common.imitation.dagger`."""
    from capture_bench.engine.task import resolve_scenario
    from capture_bench.task.episode import describe_task
    from capture_bench.training.common.imitation import dagger, make_teacher, teacher_names

    if is_mixture(config.scenario):
        scenarios, shares = mixture_scenarios(config.scenario), shares_of(config, settings)
    else:
        scenarios = [resolve_scenario(config.scenario, config.observation_source)]
        shares = [venv.num_envs]
    descriptions = [describe_task(sc) for sc in scenarios]
    assert settings.imitate is not None and settings.imitation_rounds is not None
    names = teacher_names(settings.imitate, [sc.name for sc in scenarios])
    teacher = make_teacher(names, descriptions, shares)
    raw = venv.venv  # inside VecMonitor (no VecNormalize: check_imitation)
    validate = (lambda: progress.play(model)[0]) if settings.eval_freq else None
    view = points = None
    if config.observation_source == PIXELS:  # the student sees pixels, the teacher the estimate

        def view(_obs: Any) -> Any:
            return raw.env_method("estimate_observation", indices=[0])[0]

        def points() -> Any:
            return raw.env_method("true_image_points", indices=[0])[0]

    return dagger(model, raw, teacher, settings.imitation_rounds, settings.imitation_steps,
                  settings.imitation_epochs, config.seed or 0, validate=validate,
                  floor=settings.imitation_floor, teacher_view=view, lr=settings.imitation_lr,
                  batch_size=settings.imitation_batch,
                  state_weight=settings.imitation_state_weight or 0.0,
                  store=RoundStore.of_run(config.run_dir),
                  keypoint_weight=settings.imitation_keypoint_weight or 0.0,
                  keypoint_view=points)  # fmt: skip


def resolved_yaml(config: TrainConfig, settings: TrainingSettings, origin: dict) -> str:
    """The run's resolved hyper-parameters as a YAML file that ``--config`` reads back."""
    import yaml

    layers = []
    defaults = origin.get("defaults")
    if defaults:
        layers.append(f"  defaults: {defaults['file']}")
        if defaults["section"]:
            layers.append(f"  defaults section: {defaults['section']}")
    layers.append(f"  file: {origin['file']}")
    if origin["section"]:
        layers.append(f"  section: {origin['section']}")
    layers += [f"  --set {item}" for item in origin["overrides"]]
    header = (
        f"# The resolved hyper-parameters of {config.algo.upper()} on {config.scenario}, from\n"
        + "".join(f"#{line}\n" for line in layers)
        + f"# Train again with: python train.py --algo {config.algo} --config <this file>\n"
    )
    return header + yaml.safe_dump(settings.to_mapping(), sort_keys=False)


def _check_device(device: str) -> None:
    """``cuda`` where torch sees no CUDA device is an error, not a silent CPU run."""
    if device != "cuda":
        return
    import torch

    if not torch.cuda.is_available():
        build = "built without CUDA" if torch.version.cuda is None else "no CUDA device visible"
        raise ConfigError(
            f"--device cuda: torch {torch.__version__} has no CUDA device here ({build}); "
            "use --device cpu (or auto)"
        )


def _available_memory() -> int | None:
    """Bytes of memory available to new processes (Linux's MemAvailable), or None."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _memory_available() -> int | None:
    """Bytes of memory a new run may count on: Linux's MemAvailable, else the machine's physical
    memory (``os.sysconf``), else None (unknown: not checked)."""
    available = _available_memory()
    if available is not None:
        return available
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):
        return None


def _size(count: float) -> str:
    """A byte count in words: ``512 MiB``, ``3.6 PiB``."""
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if count < 1024 or unit == "PiB":
            return (
                f"{count:.0f} {unit}" if count >= 100 or unit == "bytes" else f"{count:.1f} {unit}"
            )
        count /= 1024
    raise AssertionError("unreachable")


def _check_option_bounds(n_envs: int, total_timesteps: int) -> None:
    """``--n-envs`` and ``--total-timesteps`` within the limits the hyper-parameter files have
    (`TRAINING_KEYS`)."""
    for key, value in (("n_envs", n_envs), ("total_timesteps", total_timesteps)):
        high = int(TRAINING_KEYS[key].high)
        if value > high:
            raise ConfigError(f"--{key.replace('_', '-')} {value}: at most {high}")


def _check_memory(config: TrainConfig, settings: TrainingSettings, resume: bool = False) -> None:
    """Refuse a run whose envs, buffers, networks and update batch
    (`memory_estimate`) need more than
    `MEMORY_SHARE` of the memory available, naming the keys of the largest part."""
    available = _memory_available()
    if available is None:
        return
    batched = config.vec_env == "batched" or is_mixture(config.scenario)
    envs = int(settings.n_envs) * (BATCHED_ENV_MEMORY_BYTES if batched else ENV_MEMORY_BYTES)
    parts = settings.memory_estimate(config.observation_source == PIXELS, resume)
    total = envs + sum(size for _, _, size in parts)
    limit = available * MEMORY_SHARE
    if total <= limit:
        return
    keys, what, size = max(parts, key=lambda part: part[2])
    raise ConfigError(
        f"{keys}: ~{_size(size)} for {what}; with the rest of the run (~{_size(total - size)}, "
        f"the envs included) that is more than the {_size(limit)} train.py may use "
        f"({MEMORY_SHARE:.0%} of the {_size(available)} of memory available); choose smaller "
        "values"
    )


def _check_env_count(n_envs: int, vec_env: str) -> None:
    """Refuse more environments than the memory available can hold (they would swap or hang)."""
    available = _available_memory()
    if available is None:
        return
    each = BATCHED_ENV_MEMORY_BYTES if vec_env == "batched" else ENV_MEMORY_BYTES
    most = max(1, int(available * MEMORY_SHARE // each))
    if n_envs > most:
        raise ConfigError(
            f"--n-envs {n_envs}: at most {most} {vec_env} environments fit in the "
            f"{available / 2**30:.1f} GiB of memory available (~{each >> 20} MB each)"
        )


def note_rounding(settings: TrainingSettings, done: int = 0) -> None:
    """Print a note where SB3 will run more steps than asked (`planned_steps`: whole rollouts, or
    whole steps of all envs) or learn
    nothing (an off-policy budget within ``learning_starts``)."""
    algo = settings.algo
    total, unit = settings.total_timesteps, settings.steps_per_update()
    if algo in OFF_POLICY:
        starts = settings.algorithm.get("learning_starts", 100)
        if total <= starts:
            print(f"note: {total} steps is not more than learning_starts {starts}: "
                  "the policy will not be updated")  # fmt: skip
        why = f"train_freq x n_envs = {unit} steps at a time (all envs step together)"
    else:
        why = f"whole rollouts of n_steps x n_envs = {unit} steps"
    end = settings.planned_steps(done)
    if end != total:
        since = f" from step {done}" if done else ""
        print(f"note: {algo.upper()} trains in {why}: the budget of {total} steps{since} is "
              f"rounded up to {end}")  # fmt: skip


def train(
    config: TrainConfig, settings: TrainingSettings, run_dir: Path, checkpoint: Path | None
) -> int:
    """Build the envs and the model (and restore the checkpoint), learn, and save the result."""
    from capture_bench.training.callbacks import Checkpointer, Progress, RolloutMetrics

    algo = config.algo
    venv = build_venv(config, settings)
    tb = str(run_dir / "tb")
    model = build_model(config, settings, venv, tb)
    if settings.augment_shift:  # DrQ: the training batches' images shifted, never the env's
        from capture_bench.training.common.augmentation import install_random_shift

        install_random_shift(model.policy, settings.augment_shift)
    seed_note = f"seed {config.seed}"
    if checkpoint is not None:
        try:
            restore(model, read_checkpoint(checkpoint))  # read again: nothing unpickled
        except CheckpointError:
            close_envs(venv, interrupted=False)
            raise
        model.set_random_seed((config.seed or 0) + model.num_timesteps)  # fresh episode draws
        seed_note = f"resuming {checkpoint.name}"
    target = settings.planned_steps(model.num_timesteps)  # the step SB3 stops at
    source = config.observation_source or "each scenario's own estimate"
    envs = f"{config.n_envs} {config.vec_env} envs"
    if is_mixture(config.scenario):
        names = [s.name for s in mixture_scenarios(config.scenario)]
        shares = shares_of(config, settings)
        envs += " (" + ", ".join(f"{n} {k}" for n, k in zip(names, shares)) + ")"
    print(
        f"training {algo.upper()} on {config.scenario} ({source}), "
        f"{envs}, {seed_note}, {target} steps -> {run_dir}"
    )
    print(f"TensorBoard: tensorboard --logdir {tb}")
    checkpoints = run_dir / "checkpoints"
    checkpointer = Checkpointer(checkpoints, settings.checkpoint_freq, algo in OFF_POLICY)
    progress = Progress(config, settings, target)
    callbacks = [checkpointer, RolloutMetrics(), progress, *curriculum_callbacks(config, settings)]
    start = time.perf_counter()
    status, imitating = 0, False
    try:
        if settings.imitate is not None:  # a resumed run's warm-up goes on frozen where it stopped
            from capture_bench.training.common.imitation import FrozenActor

            callbacks.append(FrozenActor(settings.imitation_warmup))
        imitating = checkpoint is None and settings.imitate is not None
        if imitating:
            done = imitate(config, settings, model, venv, progress)
            atomic_write(run_dir / IMITATION_FILE, json.dumps(done, indent=2).encode())
            imitating = False
            progress.validate_at_start = True  # the imitated policy's validation, at step 0
            progress.extra_wall_s = time.perf_counter() - start  # on the curves' clock too
        model.learn(
            total_timesteps=max(target - model.num_timesteps, 0),
            callback=callbacks,
            reset_num_timesteps=checkpoint is None,
            tb_log_name="run",
        )
    except KeyboardInterrupt as exc:
        status = exit_status(exc)
        if imitating:  # the imitation goes on from its last complete round
            add_wall_time(run_dir, time.perf_counter() - start)
            kept = RoundStore.of_run(run_dir).rounds_done()
            print(f"\ninterrupted during the imitation ({kept} complete rounds kept); go on "
                  f"with: python train.py --resume {run_dir}")  # fmt: skip
            return status
        path = checkpointer.save(model)
        RoundStore.of_run(run_dir).clear()  # the checkpoint holds the imitated policy
        add_wall_time(run_dir, time.perf_counter() - start)
        print(f"\ninterrupted at {model.num_timesteps} steps; checkpoint {path}; "
              f"continue with: python train.py --resume {run_dir}")  # fmt: skip
    finally:
        progress.close()
        close_envs(venv, interrupted=status != 0)
    if status:
        return status
    checkpointer.save(model)
    RoundStore.of_run(run_dir).clear()  # the checkpoint holds the imitated policy
    wall = time.perf_counter() - start
    total_wall = add_wall_time(run_dir, wall)
    save_final(model, config, settings, run_dir, total_wall)
    print(f"done: {model.num_timesteps} steps in {wall:.0f} s; model: {run_dir / 'policy.pt'}")
    return 0


def add_wall_time(run_dir: Path, seconds: float) -> float:
    """Add a session's training time to ``run_dir/wall_time.json``; return the total, s."""
    from capture_bench.training.common.policy_export import WALL_TIME_FILE, recorded_wall_time

    path = run_dir / WALL_TIME_FILE
    total = recorded_wall_time(run_dir) + seconds
    atomic_write(path, json.dumps({"wall_time_s": round(total, 1)}).encode())
    return total


def save_final(
    model: Any,
    config: TrainConfig,
    settings: TrainingSettings,
    run_dir: Path,
    total_wall: float,
) -> None:
    """Write the policy in the safe form (``policy.pt`` + declared ``metadata.json``, loaded
    without unpickling: `capture_bench.agents.policy_file`), and SB3's own ``model.zip`` (+
    ``vecnormalize.pkl``) for SB3 users who trust the run."""
    from capture_bench.training.common.policy_export import (
        export_policy,
        policy_metadata,
        save_sb3_files,
    )

    save_sb3_files(run_dir, model)
    metadata = policy_metadata(model, config, settings, total_wall, sb3_files=True)
    export_policy(run_dir, model, metadata)
