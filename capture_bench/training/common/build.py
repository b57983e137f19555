"""What every training job builds and checks the same way: the option checks a run's
hyper-parameters pass (observation, imitation, curricula, shaping), the training envs
(`build_venv`: batched, ``dummy`` or ``subproc``, a mixture's scenarios side by side, the residual
and ``VecNormalize`` wrappers), the SB3 model (`build_model`), the curricula as callbacks
(`curriculum_callbacks`) and closing the envs (`close_envs`).

``train.py`` (`capture_bench.training.common.run`), ``tune.py``'s trials, the RL Zoo's
hyper-parameter files and the sweep's and curves' run plans share these, so a trial, a Zoo run
and a train.py run build the same thing from the same options.
"""

from __future__ import annotations

import itertools
import os
import signal
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from capture_bench.sensing.sources import PIXELS
from capture_bench.task.scenarios import CONFIG_DIR, ConfigError, load_scenario
from capture_bench.training.common.mixture import (
    MixtureVecEnv,
    is_mixture,
    mixture_scenarios,
    mixture_shares,
)
from capture_bench.training.config.hyperparameters import (
    OFF_POLICY,
    PIXEL_OPTION_KEYS,
    algorithm_class,
)
from capture_bench.training.config.options import (
    TrainConfig,
)
from capture_bench.training.config.settings import TrainingSettings
from capture_bench.training.seeds import TrainingSeeds

#: torch's intra-op threads in training unless ``OMP_NUM_THREADS`` is set (torch then keeps the
#: number it read from there). One: the networks are small (a few 256-wide layers, batches of
#: <= 1024), so a second thread saves little in the update and costs a spin-waiting core that
#: the env side (the same process) and other processes need; see docs/speed.md, "Training speed".
TORCH_THREADS = 1
#: The algorithms whose policy is SB3's ``ActorCriticPolicy``: one actor and one value net, both
#: fed by the features extractor (what the asymmetric critic and the fit's state regression use).
ACTOR_CRITIC_ALGOS = ("ppo", "a2c")


def pixel_config(algo: str) -> Path:
    """The shipped hyper-parameters of ``algo`` on pixels (``configs/pixels/<algo>.yaml``; only
    some algorithms have one)."""
    return CONFIG_DIR / "pixels" / f"{algo}.yaml"


def check_observation(config: TrainConfig, settings: TrainingSettings) -> None:
    """The policy fits what the agent observes: ``MultiInputPolicy`` (a CNN on the image beside
    the arm state) for ``pixels``, ``MlpPolicy`` for an estimate; pixels train on-policy (an
    off-policy replay buffer of 84 x 84 images would hold tens of GB), on one scenario, without a
    residual base (it reads the estimate) and without ``normalize`` (the policy scales the image,
    the state is of order one)."""
    pixels = config.observation_source == PIXELS
    given = f"--observation-source {config.observation_source}"
    if pixels and is_mixture(config.scenario):
        raise ConfigError(f"{given}: train pixels on one scenario, not {config.scenario}")
    if pixels and config.algo in OFF_POLICY:
        raise ConfigError(
            f"{given}: {config.algo} keeps a replay buffer of images (tens of GB at 84 x 84); "
            "train pixels with ppo or a2c"
        )
    from capture_bench.provenance import display_path

    shipped = pixel_config(config.algo)
    hint = f" (--config {display_path(shipped)})" if pixels and shipped.is_file() else ""
    if settings.front_end is not None:
        _check_front_end(config, settings)
    elif pixels and settings.policy != "MultiInputPolicy":
        raise ConfigError(
            f"{given}: the agent sees a Dict (image, state), which policy {settings.policy} cannot "
            f"read; use policy MultiInputPolicy with features_extractor combined{hint}"
        )
    if not pixels and settings.policy == "MultiInputPolicy":
        seen = config.observation_source or "each scenario's estimate"
        raise ConfigError(
            f"policy MultiInputPolicy reads the pixel observation; train it with "
            f"--observation-source pixels, or use MlpPolicy for {seen}"
        )
    for key, bad in (("residual", "none"), ("normalize", False)):
        value = getattr(settings, key)
        if pixels and value != bad:
            raise ConfigError(
                f"{given}: {key} {value} is not available with pixels; set {key}: {bad}"
            )
    if pixels:
        from capture_bench.sensing.workspace_image import check_image_size

        try:
            check_image_size(settings.pixel_size, load_scenario(config.scenario).camera.model())
        except ValueError as exc:
            raise ConfigError(f"key 'image_size': {exc}") from None
    for key in ("image_size", *PIXEL_OPTION_KEYS, "augment_shift", "asymmetric_critic",
                "front_end"):  # fmt: skip
        if getattr(settings, key) not in (None, False) and not pixels:
            seen = config.observation_source or "each scenario's estimate"
            raise ConfigError(
                f"key {key!r} shapes the pixel observation; train with --observation-source "
                f"pixels, or drop it for {seen}"
            )
    if pixels:
        _check_pixel_options(config, settings)
    features = settings.policy_kwargs.get("features_extractor")
    if features == "marker_keypoints" and settings.asymmetric_critic:
        raise ConfigError(
            "asymmetric_critic with features_extractor marker_keypoints: the asymmetric policy is "
            "stored through the per-image extractors of combined or keypoints; use one of those, "
            "or leave asymmetric_critic out"
        )
    if features == "marker_keypoints" and settings.imitate is None:
        raise ConfigError(
            "features_extractor marker_keypoints: its features are standardised on the "
            "imitation's data set before each fit; set imitate (e.g. imitate: dls, with "
            "imitation_keypoint_weight: 1 to fit its reader to the markers)"
        )
    if settings.asymmetric_critic and (
        config.algo not in ACTOR_CRITIC_ALGOS or config.vec_env != "batched"
    ):
        raise ConfigError(
            f"asymmetric_critic: the critic's true state comes from the batched env to PPO's or "
            f"A2C's value net; use --algo ppo or a2c with --vec-env batched (got {config.algo}, "
            f"{config.vec_env})"
        )


def _check_front_end(config: TrainConfig, settings: TrainingSettings) -> None:
    """A front end (`capture_bench.agents.marker_pose`) turns the pixel observation's newest
    wide image and the arm's state into a vector: the policy is ``MlpPolicy`` on it, and the
    pixel options and methods that shape what a network reads of the image (a frame stack, the
    end-effector crop, the random shift, the asymmetric critic) have nothing to act on."""
    if config.observation_source != PIXELS:
        return  # refused below, with the other pixel keys
    name = settings.front_end
    if settings.policy != "MlpPolicy":
        raise ConfigError(
            f"front_end {name}: the policy reads the front end's vector, not the image; use "
            f"policy MlpPolicy, not {settings.policy}"
        )
    features = settings.policy_kwargs.get("features_extractor", "flatten")
    if features != "flatten":
        raise ConfigError(
            f"front_end {name}: the policy reads the front end's vector as it is; set "
            f"policy_kwargs.features_extractor: flatten, not {features}"
        )
    for key in ("ee_crop", "augment_shift", "asymmetric_critic"):
        if getattr(settings, key):
            raise ConfigError(
                f"front_end {name} reads the newest wide image alone, so {key} has nothing to "
                f"act on; leave {key} out"
            )
    if (settings.frame_stack or 1) > 1:
        raise ConfigError(
            f"front_end {name} reads the newest wide image and stacks its own steps "
            f"(front_end_stack); set frame_stack 1, not {settings.frame_stack}"
        )


def _check_pixel_options(config: TrainConfig, settings: TrainingSettings) -> None:
    """The pixel options, as the env checks them (the crop must fit on the scenario's
    sensor)."""
    from capture_bench.engine.task import CaptureTask

    try:
        CaptureTask(config.scenario, observation_source=PIXELS, **settings.pixel_options)
    except ValueError as exc:
        raise ConfigError(f"the pixel observation's keys: {exc}") from None


def shares_of(config: TrainConfig, settings: TrainingSettings) -> list[int]:
    """The sub-envs of each scenario of ``config``'s mixture, in its order
    (`mixture_shares` of the settings' ``mixture_weights``)."""
    names = [s.name for s in mixture_scenarios(config.scenario)]
    n_envs = config.n_envs or settings.n_envs
    return mixture_shares(n_envs, names, settings.mixture_weights)


def fill_curriculum_steps(settings: TrainingSettings) -> TrainingSettings:
    """The settings, a curriculum without ``curriculum_steps`` given half the run's
    ``total_timesteps`` (`TrainingSettings.with_curriculum_steps`)."""
    return settings.with_curriculum_steps()


def check_curricula(settings: TrainingSettings, scenario: Any) -> None:
    """A curriculum starts on the easy side of the scenario's rule and moves to it: a tolerance
    above its epsilon, a hold below its ``capture.hold``."""
    hold, eps = scenario.capture.hold, scenario.capture_tolerance
    start_hold, start_tolerance = settings.curriculum_hold, settings.curriculum_tolerance
    if start_hold is not None and not start_hold < hold:
        raise ConfigError(
            f"curriculum_hold {start_hold:g} s is not below {scenario.name}'s "
            f"capture.hold {hold:g} s; the curriculum grows the hold to it (e.g. "
            "--scenario grasp --set curriculum_hold=0)"
        )
    if start_tolerance is not None and not start_tolerance > eps:
        raise ConfigError(
            f"curriculum_tolerance {start_tolerance:g} m is not above "
            f"{scenario.name}'s capture tolerance {eps:g} m; the curriculum shrinks it to that"
        )


def check_imitation(config: TrainConfig, settings: TrainingSettings, scenarios: list[str]) -> None:
    """``imitate`` fits a policy to a controller that reads the estimate-fed observation (with
    pixels, that of the step the student sees: the batched env only), and leaves the
    learned policy alone: `IMITATORS` (PPO, A2C: the mean; SAC, TQC: the actor's deterministic
    action), no residual and
    no VecNormalize (whose statistics the controller would not see); a controller per scenario
    names only ``scenarios`` (the run's) and gives each one."""
    if settings.imitate is None:
        return
    from capture_bench.training.common.imitation import IMITATORS, describe_teacher, teacher_names

    teacher_names(settings.imitate, scenarios)
    teacher = describe_teacher(settings.imitate)
    if config.algo not in IMITATORS:
        raise ConfigError(
            f"imitate {teacher}: fits the policy of {', '.join(IMITATORS)}, not {config.algo}"
        )
    if settings.residual != "none":
        raise ConfigError(
            f"imitate {teacher} with residual {settings.residual}: a hybrid already acts through "
            "its controller; choose one"
        )
    if settings.normalize:
        raise ConfigError(
            f"imitate {teacher}: the controller reads the raw observation; set normalize: false"
        )
    if settings.imitation_state_weight and (
        config.observation_source != PIXELS or config.algo not in ACTOR_CRITIC_ALGOS
    ):
        raise ConfigError(
            f"imitation_state_weight {settings.imitation_state_weight:g}: the fit's regression of "
            "the teacher's observation is for a pixel student of ppo or a2c (--observation-source "
            f"pixels); this run is {config.algo} on {config.observation_source}: leave it out"
        )
    if settings.imitation_state_weight and settings.front_end is not None:
        raise ConfigError(
            f"imitation_state_weight {settings.imitation_state_weight:g} with front_end "
            f"{settings.front_end}: the regression shapes the policy's features extractor, and "
            "the front end's vector reaches the policy through flatten, which has nothing to "
            "shape (the policy comes out the same); leave the weight out"
        )
    features = settings.policy_kwargs.get("features_extractor")
    if settings.imitation_keypoint_weight and (
        config.observation_source != PIXELS
        or config.algo not in ACTOR_CRITIC_ALGOS
        or features != "marker_keypoints"
    ):
        raise ConfigError(
            f"imitation_keypoint_weight {settings.imitation_keypoint_weight:g}: the fit's "
            "keypoint targets are for the markers' reader of a pixel student of ppo or a2c "
            "(--observation-source pixels, policy_kwargs.features_extractor: marker_keypoints); "
            f"this run is {config.algo} on {config.observation_source} with features "
            f"{features or 'default'}: set that extractor, or leave the weight out"
        )
    if config.observation_source == PIXELS and config.vec_env != "batched":
        raise ConfigError(
            f"imitate {teacher} with pixels: the controller reads the estimate of the step the "
            f"student sees, which the batched env gives; use --vec-env batched, not "
            f"{config.vec_env}"
        )


def check_shaping(reward: str, gamma: float) -> None:
    """``reward: shaped`` is potential-based only for the discount it assumes (``gamma``:
    `TrainingSettings.gamma`)."""
    from capture_bench.task.rewards import SHAPING_GAMMA

    if reward == "shaped" and gamma != SHAPING_GAMMA:
        raise ConfigError(
            f"reward shaped is potential-based shaping for gamma {SHAPING_GAMMA} "
            f"(capture_bench/task/rewards.py), but gamma is {gamma}; set gamma={SHAPING_GAMMA} "
            "or use reward dense"
        )


def make_env(config: TrainConfig, settings: TrainingSettings, rank: int, subprocess: bool) -> Any:
    """A thunk building environment ``rank``: CaptureEnv with training seeds only."""

    def thunk() -> Any:
        if subprocess:  # signals are the main process's: it saves, then ends the workers
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
        from capture_bench.envs.capture_env import CaptureEnv

        scenario = load_scenario(config.scenario)
        env = CaptureEnv(
            scenario,
            observation_source=config.observation_source,
            reward=settings.reward,
            **settings.pixel_options,
        )
        return TrainingSeeds(env, scenario, seed=(config.seed or 0) * 1000 + rank)

    return thunk


def build_venv(config: TrainConfig, settings: TrainingSettings) -> Any:
    """The training envs of ``config.vec_env`` in a ``VecMonitor`` (and ``VecNormalize`` where
    ``settings.normalize``): ``batched`` (`
    CaptureSB3VecEnv`, one process), or SB3's ``dummy`` / ``subproc`` vector envs of single
    ``CaptureEnv``s; all draw the same training-seed episodes."""
    from stable_baselines3.common.vec_env import (
        DummyVecEnv,
        SubprocVecEnv,
        VecMonitor,
        VecNormalize,
    )

    n_envs = config.n_envs or 1
    venv: Any
    if is_mixture(config.scenario):  # each scenario's share of the sub-envs, side by side
        from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

        scenarios, shares = mixture_scenarios(config.scenario), shares_of(config, settings)
        venv = MixtureVecEnv([
            CaptureSB3VecEnv(share, sc, seed=(config.seed or 0) * 1000 + k, reward=settings.reward)
            for k, (sc, share) in enumerate(zip(scenarios, shares, strict=True))
        ])  # fmt: skip
    elif config.vec_env == "batched":
        from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

        venv = CaptureSB3VecEnv(
            n_envs,
            config.scenario,
            seed=config.seed or 0,
            observation_source=config.observation_source,
            reward=settings.reward,
            critic_state=bool(settings.asymmetric_critic),
            **settings.pixel_options,
        )
    else:
        subprocess = config.vec_env == "subproc"
        fns = [make_env(config, settings, i, subprocess) for i in range(n_envs)]
        venv = SubprocVecEnv(fns) if subprocess else DummyVecEnv(fns)
    front_end = settings.front_end_spec
    if front_end is not None:  # the policy reads the front end's vector of the image
        from capture_bench.training.common.front_end_vec_env import FrontEndVecEnv

        calibration = front_end.calibration(config.scenario)
        venv = FrontEndVecEnv(venv, calibration, front_end.stack)
    venv = VecMonitor(venv)
    if settings.residual != "none":  # a hybrid: the policy's action is a residual on the base
        from capture_bench.engine.task import resolve_scenario
        from capture_bench.task.episode import describe_task
        from capture_bench.training.common.residual_vec_env import ResidualVecEnv

        description = describe_task(resolve_scenario(config.scenario, config.observation_source))
        venv = ResidualVecEnv(venv, settings.residual, settings.residual_scale, description)
    if settings.normalize:
        venv = VecNormalize(venv, gamma=settings.gamma)
    return venv


def set_torch_threads() -> int:
    """Give torch `TORCH_THREADS` intra-op threads, unless the user chose a number with
    ``OMP_NUM_THREADS``; return the number torch uses."""
    import torch

    if not os.environ.get("OMP_NUM_THREADS"):
        torch.set_num_threads(TORCH_THREADS)
    return torch.get_num_threads()


def build_model(
    config: TrainConfig, settings: TrainingSettings, venv: Any, tensorboard_log: str | None
) -> Any:
    """The SB3 (or sb3-contrib) algorithm of ``config.algo`` on ``venv`` with ``settings`` (torch
    threads: `set_torch_threads`)."""
    set_torch_threads()
    algorithm = algorithm_class(config.algo)
    policy: Any = settings.policy
    if settings.asymmetric_critic:  # the critic also reads the true state (training only)
        from capture_bench.training.common.asymmetric import AsymmetricActorCriticPolicy

        policy = AsymmetricActorCriticPolicy
    return algorithm(
        policy, venv, seed=config.seed, device=config.device,
        tensorboard_log=tensorboard_log, **settings.sb3_kwargs(),
    )  # fmt: skip


def curricula(settings: TrainingSettings, scenario: Any) -> dict[str, dict[str, Any]]:
    """The curricula ``settings`` asks for on ``scenario`` (training only), by the name of their
    callback in `capture_bench.training.callbacks`, with its keyword arguments:
    ``{"ToleranceCurriculum": {"start": m, "final": eps (m, 3 numbers), "steps": ..., "delay":
    ...}, "HoldCurriculum": {"start": s, "final": capture.hold (s), ...}}``; empty where it asks
    for none. ``settings`` holds ``curriculum_steps`` (`fill_curriculum_steps`)."""
    if not settings.has_curriculum:
        return {}
    from capture_bench.task.episode import describe_task

    schedule = {"steps": settings.curriculum_steps, "delay": settings.curriculum_delay}
    found: dict[str, dict[str, Any]] = {}
    if settings.curriculum_tolerance is not None:
        final = [float(x) for x in describe_task(scenario).capture_tolerance]
        found["ToleranceCurriculum"] = {"start": settings.curriculum_tolerance, "final": final}
    if settings.curriculum_hold is not None:
        final_hold = scenario.capture.hold
        found["HoldCurriculum"] = {"start": settings.curriculum_hold, "final": final_hold}
    return {name: {**kwargs, **schedule} for name, kwargs in found.items()}


def mixture_curricula(
    settings: TrainingSettings, scenarios: Sequence[Any], shares: Sequence[int]
) -> list[tuple[str, dict[str, Any]]]:
    """A mixture's curricula, scenario by scenario: each of `curricula` on a scenario
    where it moves (a hold curriculum where ``curriculum_hold`` is below the scenario's
    ``capture.hold``, a tolerance one where ``curriculum_tolerance`` is above its epsilon; the
    others keep their rule), bound to that scenario's sub-envs of the
    `MixtureVecEnv` (``indices``: its ``shares[k]``,
    after the earlier scenarios') and labelled by it."""
    out = []
    offsets = [0, *itertools.accumulate(shares)]
    for k, scenario in enumerate(scenarios):
        for name, kwargs in curricula(settings, scenario).items():
            if name == "HoldCurriculum" and not kwargs["start"] < kwargs["final"]:
                continue
            if name == "ToleranceCurriculum" and not kwargs["start"] > max(kwargs["final"]):
                continue
            indices = list(range(offsets[k], offsets[k + 1]))
            out.append((name, {**kwargs, "indices": indices, "label": scenario.name}))
    return out


def curriculum_callbacks(config: TrainConfig, settings: TrainingSettings) -> list[Any]:
    """The curricula ``settings`` asks for (training only: validation keeps the scenario's rule), as
    SB3 callbacks (`curricula`; on a mixture, one per scenario it moves on,
    `mixture_curricula`); none where it asks for none (a mixture's spec, which names no
    one scenario, is then never loaded)."""
    if not settings.has_curriculum:
        return []
    from capture_bench.training import callbacks

    if is_mixture(config.scenario):
        scenarios, shares = mixture_scenarios(config.scenario), shares_of(config, settings)
        found = mixture_curricula(settings, scenarios, shares)
    else:
        found = list(curricula(settings, load_scenario(config.scenario)).items())
    return [getattr(callbacks, name)(**kwargs) for name, kwargs in found]


def close_envs(venv: Any, interrupted: bool) -> None:
    """Close the vectorised envs; after an interrupt, kill subprocess workers instead.

    The signal can land while the main process waits on the workers' pipes; SB3's graceful close
    would then wait for replies already consumed, forever (seen on the 16-env device run). The
    workers ignore SIGINT and SIGTERM (the main process handles them), so they are killed.
    """
    base = venv.unwrapped
    if interrupted and hasattr(base, "processes"):
        for process in base.processes:
            process.kill()
        for process in base.processes:
            process.join(timeout=5)
        base.closed = True
        return
    venv.close()
