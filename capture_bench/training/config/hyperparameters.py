"""Per-algorithm hyper-parameters: ``configs/algos/<algo>.yaml`` (RL-Zoo-like keys), validated once.

An unknown key or a bad value raises [`ConfigError`][capture_bench.task.scenarios.ConfigError]
naming the
file, the key, the value and what is valid; `sb3_kwargs` turns a validated mapping into the
SB3 algorithm's constructor arguments. The training jobs pass the validated mapping on as
[`TrainingSettings`][capture_bench.training.config.settings.TrainingSettings], whose helpers
call the functions here. No SB3 or torch import happens at module level.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from capture_bench.agents.algorithms import ALGORITHMS
from capture_bench.agents.marker_pose import DEFAULT_STACK, FRONT_ENDS
from capture_bench.agents.residual import RESIDUAL_BASES, TEACHERS
from capture_bench.task.observation import OBSERVATION_SIZE, STATE_SIZE
from capture_bench.task.rewards import REWARD_MODES
from capture_bench.task.scenarios import CONFIG_DIR, Scenario
from capture_bench.validation import (
    YAML_ERRORS,
    ConfigError,
    Rule,
    Schema,
    check_mapping,
    is_file,
    read_mapping,
    shown,
)

ALGO_DIR = CONFIG_DIR / "algos"
#: Those that learn from a replay buffer (checkpoints keep it; ``learning_starts`` applies).
OFF_POLICY = ("sac", "td3", "ddpg", "tqc")
#: Where each algorithm's class lives.
ALGORITHM_CLASSES = {
    "ppo": ("stable_baselines3", "PPO"),
    "a2c": ("stable_baselines3", "A2C"),
    "sac": ("stable_baselines3", "SAC"),
    "td3": ("stable_baselines3", "TD3"),
    "ddpg": ("stable_baselines3", "DDPG"),
    "tqc": ("sb3_contrib", "TQC"),
}
#: SB3's ``n_steps`` where a file leaves it out.
SB3_N_STEPS = {"ppo": 2048, "a2c": 5}
ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU"}


#: SB3 policy names a file may give: ``MlpPolicy`` for the estimate's Box observation,
#: ``MultiInputPolicy`` for the pixel observation's ``Dict`` (train.py pairs each with its source).
POLICIES = ("MlpPolicy", "MultiInputPolicy")
#: The features extractor each policy reads its observation with, where the file gives none.
DEFAULT_FEATURES = {"MlpPolicy": "flatten", "MultiInputPolicy": "combined"}
DICT_FEATURES = ("combined", "keypoints", "marker_keypoints")  # those that read a Dict one

# Counts SB3 and numpy hold as machine integers: at most 2**53 (exact as a float, fits an int64).
MOST = 2**53
POS_INT, NONNEG_INT = Rule("int", 1, MOST), Rule("int", 0, MOST)
UNIT, NONNEG = Rule("float", 0.0, 1.0), Rule("float", 0.0)
# Upper bounds of the keys that size memory: the envs, the rollout or replay buffer, the networks
# and their update batch, the imitation's data set. Each lies far above what any shipped config
# or experiment uses (n_envs 64, n_steps 64, batch_size 1024, buffer_size 500000, layers of 256,
# 6 rounds of 400000 imitation steps), so that a typing slip is refused by its key at once; what
# the limits still allow is checked against the machine's memory before anything is built
# (memory_estimate, train.py's check). total_timesteps sizes no memory (at most MOST).
MAX_ENVS = 65536  # n_envs (sub-envs of the batched env, or single envs)
MAX_ROLLOUT_STEPS = 2**19  # n_steps, per env (524288)
MAX_BATCH = 2**19  # batch_size (524288)
MAX_BUFFER = 100_000_000  # buffer_size, transitions
MAX_LAYER_WIDTH = 65536  # each width of policy_kwargs.net_arch (the safe policy format's bound)
MAX_LAYERS = 64  # widths in one policy_kwargs.net_arch list
MAX_HEADS = 1000  # policy_kwargs.n_critics and n_quantiles (the safe policy format's bound)
MAX_IMITATION_ROUNDS = 1000
MAX_IMITATION_STEPS = 100_000_000  # environment steps per round, all sub-envs together
TRAINING_KEYS = {
    "n_envs": Rule("int", 1, MAX_ENVS),
    "total_timesteps": POS_INT,
    # MultiInputPolicy: the pixel observation's Dict (image and arm state), with ``combined``
    "policy": Rule("choice", choices=POLICIES),
    "policy_kwargs": Rule("mapping"),
    "normalize": Rule("bool"),
    "reward": Rule("choice", choices=REWARD_MODES),
    "checkpoint_freq": NONNEG_INT,
    "eval_freq": NONNEG_INT,
    "eval_episodes": POS_INT,
    # a hybrid (capture_bench/agents/residual.py): the policy learns a residual on this controller
    "residual": Rule("choice", choices=("none", *RESIDUAL_BASES)),
    "residual_scale": Rule("float", 0.0, 1.0, low_inclusive=False),  # alpha
    # a tolerance curriculum, training only: eq. 20 counts a capture at curriculum_tolerance (m)
    # at first, shrinking geometrically to the scenario's epsilon over curriculum_steps
    "curriculum_tolerance": Rule("float", 0.0, 1.0, low_inclusive=False),
    # imitation first (capture_bench/training/common/imitation.py): DAgger from this analytic
    # controller (or, in a mixture, one per scenario: {default: <controller>, <scenario>:
    # <controller>}),
    # imitation_rounds rounds of imitation_steps environment steps, imitation_epochs passes of the
    # fit after each; then imitation_warmup steps of the algorithm train the critic alone
    "imitate": Rule("choice_per_name", choices=TEACHERS),
    "imitation_rounds": Rule("int", 1, MAX_IMITATION_ROUNDS),
    "imitation_steps": Rule("int", 1, MAX_IMITATION_STEPS),
    "imitation_epochs": POS_INT,
    "imitation_warmup": NONNEG_INT,
    # > 0: the fit weighs each label by 1 / (|a|^2 + imitation_floor^2), the error relative to
    # the teacher's action a (the small last steps onto the capture point as much as the rest)
    "imitation_floor": Rule("float", 0.0, 10.0),
    # the fit's Adam learning rate and minibatch size (a pixel student needs smaller steps than
    # a policy on the 16 numbers of the observation: docs/pixels.md)
    "imitation_lr": Rule("float", 0.0, 1.0, low_inclusive=False),
    "imitation_batch": POS_INT,
    # > 0, pixels (ppo, a2c): the fit also regresses the teacher's estimate-fed observation from
    # the actor's features, this weight times its squared error (imitation.StateTargets)
    "imitation_state_weight": Rule("float", 0.0, 100.0),
    # > 0, pixels (ppo, a2c) with marker_keypoints: the fit also fits the reader's keypoints to
    # the markers' true image points, this weight times their loss (imitation.KeypointTargets)
    "imitation_keypoint_weight": Rule("float", 0.0, 100.0),
    # a mixture's sub-envs per scenario, relative to the scenarios it leaves out (weight 1 each):
    # {grasp: 4} gives grasp four times the share of each other scenario (mixture.mixture_shares)
    "mixture_weights": Rule("weights"),
    # a hold curriculum, training only: a capture must hold curriculum_hold s (0: the first entry
    # captures, a fly-through) at first, growing linearly to the scenario's capture.hold over
    # curriculum_steps (grasp: PPO finds the capture by flying through, then learns to stay)
    "curriculum_hold": Rule("float", 0.0, 10.0),
    "curriculum_steps": POS_INT,
    "curriculum_delay": NONNEG_INT,  # steps at the starting value before either curriculum moves
    # with observation_source pixels: the image's side, pixels (square; at least NatureCNN's 36,
    # at most the shipped camera's crop, 924; train.py checks it against the scenario's camera)
    "image_size": Rule("int", 36, 924),
    # with pixels, the observation's options (capture_bench/sensing/workspace_image.py's
    # PixelOptions; left out: the original observation): the last frame_stack images along the
    # channels; an ee_crop x ee_crop pixel crop centred on the end-effector (at least NatureCNN's
    # 36), ee_crop_scale sensor pixels a pixel; image_supersample / ee_crop_supersample samples
    # a side per pixel, averaged
    "frame_stack": Rule("int", 1, 16),
    "ee_crop": Rule("int", 36, 256),
    "ee_crop_scale": Rule("int", 1, 11),
    "image_supersample": Rule("int", 1, 11),
    "ee_crop_supersample": Rule("int", 1, 11),
    # with pixels, DrQ's random shift of the training batches' images by up to augment_shift
    # pixels (capture_bench/training/common/augmentation.py); 0 or left out: none
    "augment_shift": Rule("int", 0, 16),
    # with pixels (ppo, a2c): the critic also reads the true state, the actor the pixels alone
    # (capture_bench/training/common/asymmetric.py); training only
    "asymmetric_critic": Rule("bool"),
    # with pixels: the policy network reads the target's pose that a front end reads from the
    # image (capture_bench/agents/marker_pose.py: marker_pose, the hand-read markers through the
    # estimator's photogrammetry), over its last front_end_stack steps, beside the arm's state
    "front_end": Rule("choice", choices=FRONT_ENDS),
    "front_end_stack": Rule("int", 1, 16),
}
#: The keys of ``TRAINING_KEYS`` that are the pixel observation's options, env keyword arguments.
PIXEL_OPTION_KEYS = (
    "frame_stack",
    "ee_crop",
    "ee_crop_scale",
    "image_supersample",
    "ee_crop_supersample",
)
#: What an imitation leaves out takes: 4 rounds of 200k steps, 10 passes each of Adam at 1e-3 on
#: minibatches of 1024, no warm-up, no auxiliary regression.
IMITATION_DEFAULTS = {
    "imitation_rounds": 4,
    "imitation_steps": 200_000,
    "imitation_epochs": 10,
    "imitation_warmup": 0,
    "imitation_floor": 0.0,
    "imitation_lr": 1e-3,
    "imitation_batch": 1024,
    "imitation_state_weight": 0.0,
    "imitation_keypoint_weight": 0.0,
}
#: The curricula that ``curriculum_steps`` schedules (each key: its starting value).
CURRICULA = ("curriculum_tolerance", "curriculum_hold")
_SDE = {"use_sde": Rule("bool"), "sde_sample_freq": Rule("int", -1)}
_ON = {  # PPO and A2C (OnPolicyAlgorithm)
    "learning_rate": Rule("schedule"),
    "gamma": UNIT,
    "n_steps": Rule("int", 2, MAX_ROLLOUT_STEPS),
    "gae_lambda": UNIT,
    "ent_coef": NONNEG,
    "vf_coef": NONNEG,
    "max_grad_norm": NONNEG,
    "normalize_advantage": Rule("bool"),
    **_SDE,
}
_OFF = {  # OffPolicyAlgorithm
    "learning_rate": Rule("schedule"),
    "gamma": UNIT,
    "batch_size": Rule("int", 1, MAX_BATCH),
    "buffer_size": Rule("int", 1, MAX_BUFFER),
    "learning_starts": NONNEG_INT,
    "tau": UNIT,
    "train_freq": POS_INT,
    "gradient_steps": Rule("int", -1),
}
_ENTROPY = {  # SAC and TQC: entropy-regularised, squashed Gaussian actor
    "ent_coef": Rule("float_or_auto"),
    "target_update_interval": POS_INT,
    "target_entropy": Rule("float_or_auto"),
    **_SDE,
    "use_sde_at_warmup": Rule("bool"),
}
_DETERMINISTIC = {  # TD3 and DDPG: deterministic actor, Gaussian exploration noise
    "action_noise_std": NONNEG,  # in action units (Box(-1, 1))
}
ALGO_KEYS: dict[str, dict[str, Rule]] = {
    "ppo": {
        **_ON,
        "batch_size": Rule("int", 1, MAX_BATCH),
        "n_epochs": POS_INT,
        "clip_range": Rule("schedule"),
        "target_kl": Rule("optional_float", 0.0),
    },
    "a2c": {
        **_ON,
        "rms_prop_eps": Rule("float", 0.0, low_inclusive=False),
        "use_rms_prop": Rule("bool"),
    },
    "sac": {**_OFF, **_ENTROPY},
    "td3": {
        **_OFF,
        **_DETERMINISTIC,
        "policy_delay": POS_INT,
        "target_policy_noise": NONNEG,
        "target_noise_clip": NONNEG,
    },
    "ddpg": {**_OFF, **_DETERMINISTIC},
    "tqc": {**_OFF, **_ENTROPY, "top_quantiles_to_drop_per_net": NONNEG_INT},
}
#: Features the network computes from the observation: the keys of
#: capture_bench.agents.features.FEATURE_EXTRACTORS (which imports torch; tests check they agree).
FEATURES = ("flatten", "relative_log_distance", "combined", "keypoints", "marker_keypoints")
_NET = {
    "activation_fn": Rule("choice", choices=tuple(ACTIVATIONS)),
    "features_extractor": Rule("choice", choices=FEATURES),
}
_ACTOR_CRITIC = {"net_arch": Rule("layers", choices=("pi", "vf")), **_NET}
_HEADS = Rule("int", 1, MAX_HEADS)
_Q = {"net_arch": Rule("layers", choices=("pi", "qf")), **_NET, "n_critics": _HEADS}
#: ``policy_kwargs`` each algorithm's SB3 policy accepts (of those the safe policy format
#: declares: `capture_bench.agents.policy_file`).
POLICY_KWARGS: dict[str, dict[str, Rule]] = {
    "ppo": {**_ACTOR_CRITIC, "log_std_init": Rule("float"), "ortho_init": Rule("bool")},
    "a2c": {**_ACTOR_CRITIC, "log_std_init": Rule("float"), "ortho_init": Rule("bool")},
    "sac": {**_Q, "log_std_init": Rule("float")},
    "td3": _Q,
    "ddpg": _Q,
    "tqc": {**_Q, "log_std_init": Rule("float"), "n_quantiles": _HEADS},
}


def _schema(algo: str) -> Schema:
    return {**TRAINING_KEYS, **ALGO_KEYS[algo], "policy_kwargs": POLICY_KWARGS[algo]}


def _check(data: Any, schema: Schema, source: str, **kwargs: Any) -> dict[str, Any]:
    """`check_mapping`, then the bounds of
    ``policy_kwargs.net_arch`` (at most `MAX_LAYERS` widths per list, each at most
    `MAX_LAYER_WIDTH`), which the ``layers`` rule leaves open."""
    out = check_mapping(data, schema, source, **kwargs)
    arch = out.get("policy_kwargs", {}).get("net_arch")
    lists = list(arch.values()) if isinstance(arch, dict) else [arch] if arch is not None else []
    if any(
        len(widths) > MAX_LAYERS or max(widths, default=1) > MAX_LAYER_WIDTH for widths in lists
    ):
        text = repr(arch) if len(repr(arch)) <= 60 else repr(arch)[:57] + "..."
        raise ConfigError(
            f"{source}: key '{kwargs.get('prefix', '')}policy_kwargs.net_arch': {text} is not "
            f"valid; expected at most {MAX_LAYERS} layer widths per list, each in "
            f"[1, {MAX_LAYER_WIDTH}]"
        )
    return out


def validate_hyperparameters(
    data: Any, algo: str, source: str, features_from: str | None = None
) -> dict[str, Any]:
    """Check a complete hyper-parameter mapping for ``algo`` (no scenario sections); return it
    with numbers in canonical form and the defaults filled in. ``features_from``: the file
    ``policy_kwargs.features_extractor`` came from where not ``source`` (for the message).

    Raises:
        ConfigError: not a mapping, an unknown key, or a bad value (the message names
            ``source``, the key, the value and what is valid).
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of hyper-parameters, got {shown(data)}")
    required = {key: TRAINING_KEYS[key].describe() for key in ("n_envs", "total_timesteps")}
    out = _check(data, _schema(algo), source, required=required)
    features = out.get("policy_kwargs", {}).get("features_extractor", "flatten")
    if features not in ("flatten", *DICT_FEATURES) and out.get("normalize"):
        raise ConfigError(
            f"{source}: key 'policy_kwargs.features_extractor': {shown(features)}"
            + (f" (from {features_from}, under this file)" if features_from else "")
            + " reads the raw observation and cannot be combined with normalize: true; set "
            "normalize: false, or policy_kwargs.features_extractor: flatten"
        )
    out.setdefault("policy", "MlpPolicy")
    out.setdefault("policy_kwargs", {})
    dict_policy = out["policy"] == "MultiInputPolicy"
    if dict_policy != (features in DICT_FEATURES) and "features_extractor" in out["policy_kwargs"]:
        fits = [f for f in FEATURES if (f in DICT_FEATURES) == dict_policy]
        raise ConfigError(
            f"{source}: key 'policy_kwargs.features_extractor': {shown(features)}"
            + (f" (from {features_from}, under this file)" if features_from else "")
            + f" does not read the observation of policy {out['policy']}; valid: "
            + ", ".join(fits)
        )
    if features == "marker_keypoints" and out.get("ee_crop"):
        raise ConfigError(
            f"{source}: key 'policy_kwargs.features_extractor': 'marker_keypoints'"
            + (f" (from {features_from}, under this file)" if features_from else "")
            + f" reads the wide image alone and cannot be combined with ee_crop: "
            f"{shown(out['ee_crop'])}; leave out ee_crop, or use keypoints or combined"
        )
    out.setdefault("normalize", False)
    out.setdefault("reward", "dense")
    out.setdefault("checkpoint_freq", 0)
    out.setdefault("eval_freq", 0)
    out.setdefault("eval_episodes", 5)
    imitation = [k for k in IMITATION_DEFAULTS if k in out]
    if imitation and "imitate" not in out:
        raise ConfigError(
            f"{source}: key {imitation[0]!r} needs imitate (the controller to imitate, one of "
            f"{', '.join(RESIDUAL_BASES)}) beside it"
        )
    if "imitate" in out:
        for key, value in IMITATION_DEFAULTS.items():
            out.setdefault(key, value)
    for key in ("curriculum_steps", "curriculum_delay"):
        if key in out and not any(curriculum in out for curriculum in CURRICULA):
            raise ConfigError(
                f"{source}: key '{key}' needs curriculum_tolerance (the starting tolerance, m) "
                "or curriculum_hold (the starting hold, s) beside it"
            )
    if any(curriculum in out for curriculum in CURRICULA):
        out.setdefault("curriculum_delay", 0)  # a run saved before the key resumes as it ran
    out.setdefault("residual", "none")
    if out["residual"] != "none":
        out.setdefault("residual_scale", 0.5)
    if "front_end_stack" in out and "front_end" not in out:
        raise ConfigError(
            f"{source}: key 'front_end_stack' needs front_end (one of {', '.join(FRONT_ENDS)}) "
            "beside it"
        )
    if "front_end" in out:
        out.setdefault("front_end_stack", DEFAULT_STACK)
    return out


def steps_per_update(algo: str, hp: dict[str, Any]) -> int:
    """Environment steps (all envs together) SB3 takes between two looks at the budget: a
    rollout of ``n_steps x n_envs`` (PPO, A2C), or ``train_freq x n_envs`` (off-policy)."""
    if algo in OFF_POLICY:
        return int(hp.get("train_freq", 1)) * int(hp["n_envs"])  # SB3's default train_freq: 1
    return int(hp.get("n_steps", SB3_N_STEPS[algo])) * int(hp["n_envs"])


def planned_steps(algo: str, hp: dict[str, Any], done: int = 0) -> int:
    """The step count a run of ``hp["total_timesteps"]`` ends at, from ``done`` steps: SB3 trains
    in whole `steps_per_update`, so the steps left are rounded up to a multiple."""
    unit = steps_per_update(algo, hp)
    return done + -(-max(hp["total_timesteps"] - done, 0) // unit) * unit


#: The action: velocity commands of the 3 joints (the envs' action space, Box(-1, 1, (3,))).
ACTION_SIZE = 3
#: What SB3 builds where ``hp`` leaves a key out (for `memory_estimate`): the networks'
#: widths, the replay buffer, the batch sizes, the quantiles of TQC's critics.
SB3_NET_ARCH = {"ppo": [64, 64], "a2c": [64, 64], "sac": [256, 256], "td3": [400, 300],
                "ddpg": [400, 300], "tqc": [256, 256]}  # fmt: skip
SB3_BUFFER_SIZE = 1_000_000
SB3_BATCH_SIZE = {"ppo": 64, "sac": 256, "td3": 256, "ddpg": 256, "tqc": 256}
SB3_N_QUANTILES = 25
#: Entries ``relative_log_distance`` appends to the observation
#: (`capture_bench.agents.features.EXTRA_SIZE`, which imports torch; a test checks that
#: they agree).
EXTRA_FEATURES = 4
#: The features of ``combined`` on the pixel observation: SB3's NatureCNN output on the image,
#: beside the flattened state.
CNN_FEATURES = 256
#: Bytes per stored number (SB3 stores float32; a uint8 image is counted as float32 too, which
#: older SB3 versions and torch's update use).
NUMBER_BYTES = 4
#: Copies of every network parameter during training: the weights, their gradients, Adam's two
#: moments, and the copy a checkpoint serialises.
PARAMETER_COPIES = 5
#: Numbers kept per activation of an update's batch: the forward value, its gradient, a margin.
ACTIVATION_COPIES = 3


def _mlp_parameters(inputs: int, widths: Sequence[int], outputs: int) -> int:
    sizes = [inputs, *widths, outputs]
    return sum(a * b + b for a, b in zip(sizes, sizes[1:], strict=False))


def _cnn(size: tuple[int, int]) -> tuple[int, int]:
    """SB3's NatureCNN on a (width, height) RGB image: (parameters, activations per image)."""
    width, height = size
    shapes = []
    for kernel, stride in ((8, 4), (4, 2), (3, 1)):
        width, height = (width - kernel) // stride + 1, (height - kernel) // stride + 1
        shapes.append(width * height)
    parameters = (3 * 32 * 64 + 32) + (32 * 64 * 16 + 64) + (64 * 64 * 9 + 64)
    parameters += 64 * shapes[-1] * CNN_FEATURES + CNN_FEATURES
    activations = 3 * size[0] * size[1] + 32 * shapes[0] + 64 * shapes[1] + 64 * shapes[2]
    return parameters, activations


def memory_estimate(
    algo: str, hp: dict[str, Any], pixels: bool, resume: bool = False
) -> list[tuple[str, str, int]]:
    """An upper estimate of the memory a run of ``algo`` with the validated ``hp`` allocates
    beyond its envs, part by part, before anything is built: ``(keys, what, bytes)``, ``keys``
    naming the hyper-parameters that size the part with their values. ``pixels``: the agent
    observes the camera's image (``image_size``); ``resume``: a checkpoint's replay buffer is
    read beside the one it fills.

    The parts: the rollout buffer (PPO, A2C: ``n_steps x n_envs`` rows of the observation, the
    action and six numbers, and the flattened copy SB3 makes of it for the update), or the replay
    buffer (off-policy: ``buffer_size`` rows of two observations, the action and three numbers);
    the networks (`PARAMETER_COPIES` copies of each parameter: actor, critics and the
    target copies, the CNN on pixels; behind a front end, its vector instead of the image and no
    CNN); an update's batch of activations; and the imitation's
    data set (``imitation_rounds x imitation_steps`` observations and labels, and the copies
    each round's fit makes).
    """
    n_envs = int(hp["n_envs"])
    kwargs = hp.get("policy_kwargs", {})
    if pixels and hp.get("front_end"):  # the front end's vector: float32 numbers, no CNN
        from capture_bench.agents.marker_pose import STEP_WIDTH

        cnn_parameters = cnn_activations = 0
        observation = features = int(hp["front_end_stack"]) * STEP_WIDTH  # set with front_end
        kept_bytes = observation * NUMBER_BYTES
    elif pixels:
        from capture_bench.sensing.workspace_image import IMAGE_SIZE

        side = image_size(hp) or IMAGE_SIZE
        cnn_parameters, cnn_activations = _cnn(side)
        stack = int(hp.get("frame_stack") or 1)
        crop = int(hp.get("ee_crop") or 0)
        pixels = 3 * stack * (side[0] * side[1] + crop * crop)
        observation = pixels + STATE_SIZE
        # the imitation keeps the images as uint8 (one byte a number), the state as float32
        kept_bytes = pixels + STATE_SIZE * NUMBER_BYTES
        features = CNN_FEATURES + STATE_SIZE
        if kwargs.get("features_extractor") == "keypoints":  # stride-1 maps: larger
            cnn_activations = 3 * stack * side[0] * side[1] + 40 * side[0] * side[1]
        if kwargs.get("features_extractor") == "marker_keypoints":  # per frame, full size
            cnn_activations = stack * 53 * side[0] * side[1]  # 3 + 16 + 4 + 10 + 16 + 4 maps
        if crop:  # a second NatureCNN, on the end-effector crop
            crop_parameters, crop_activations = _cnn((crop, crop))
            cnn_parameters += crop_parameters
            cnn_activations += crop_activations
            features += CNN_FEATURES
    else:
        cnn_parameters = cnn_activations = 0
        observation = OBSERVATION_SIZE
        kept_bytes = OBSERVATION_SIZE * NUMBER_BYTES
        features = OBSERVATION_SIZE + EXTRA_FEATURES
    arch = kwargs.get("net_arch", SB3_NET_ARCH[algo])
    second = "qf" if algo in OFF_POLICY else "vf"
    pi, other = (
        (arch.get("pi", []), arch.get(second, [])) if isinstance(arch, dict) else (arch,) * 2
    )
    arch_keys = f"policy_kwargs.net_arch {arch}"
    parts = []
    if algo in OFF_POLICY:
        heads = int(kwargs.get("n_critics", 2))
        outputs = int(kwargs.get("n_quantiles", SB3_N_QUANTILES)) if algo == "tqc" else 1
        critic = _mlp_parameters(features + ACTION_SIZE, other, outputs)
        # the actor (SAC's mean and log std) and the critics, each with its target copy
        parameters = 2 * (_mlp_parameters(features, pi, 2 * ACTION_SIZE) + heads * critic)
        buffer_size = int(hp.get("buffer_size", SB3_BUFFER_SIZE))
        rows = max(buffer_size // n_envs, 1) * n_envs
        size = rows * (2 * observation + ACTION_SIZE + 3) * NUMBER_BYTES * (2 if resume else 1)
        parts.append((f"buffer_size {buffer_size}", "the replay buffer", size))
        batch = int(hp.get("batch_size", SB3_BATCH_SIZE[algo]))
        width = features + sum(pi) + ACTION_SIZE + 2 * heads * (features + sum(other) + outputs)
        batch_keys = f"batch_size {batch}"
    else:
        parameters = cnn_parameters + ACTION_SIZE
        parameters += _mlp_parameters(features, pi, ACTION_SIZE) + _mlp_parameters(
            features, other, 1
        )
        n_steps = int(hp.get("n_steps", SB3_N_STEPS[algo]))
        rows = n_steps * n_envs
        size = 2 * rows * (observation + ACTION_SIZE + 6) * NUMBER_BYTES
        parts.append((f"n_steps {n_steps} x n_envs {n_envs}", "the rollout buffer", size))
        batch = int(hp.get("batch_size", SB3_BATCH_SIZE["ppo"])) if algo == "ppo" else rows
        width = cnn_activations + features + sum(pi) + ACTION_SIZE + sum(other) + 1
        batch_keys = (
            f"batch_size {batch}" if algo == "ppo" else f"n_steps {n_steps} x n_envs {n_envs}"
        )
    parts.append((arch_keys, "the networks", parameters * NUMBER_BYTES * PARAMETER_COPIES))
    activations = batch * width * NUMBER_BYTES * ACTIVATION_COPIES
    parts.append((f"{batch_keys} with {arch_keys}", "an update's batch", activations))
    if "imitate" in hp:
        rounds, steps = int(hp["imitation_rounds"]), int(hp["imitation_steps"])
        rows = rounds * -(-steps // n_envs) * n_envs
        size = 3 * rows * (kept_bytes + 2 * ACTION_SIZE * NUMBER_BYTES)
        keys = f"imitation_rounds {rounds} x imitation_steps {steps}"
        parts.append((keys, "the imitation's data set", size))
    return parts


def load_hyperparameters(algo: str, path: str | Path | None = None) -> tuple[dict[str, Any], Path]:
    """Read and validate one hyper-parameter file as written, complete on its own:
    ``configs/algos/<algo>.yaml`` (or ``path``), no scenario section applied, nothing layered
    under it; return it and its path. What ``train.py`` trains with is
    `resolve_hyperparameters`."""
    if algo not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {algo!r}; valid: {', '.join(ALGORITHMS)}")
    file = Path(path) if path is not None else ALGO_DIR / f"{algo}.yaml"
    top, _ = _read_layers(file, algo, None)
    return validate_hyperparameters(top, algo, str(file)), file


def resolve_hyperparameters(
    algo: str,
    scenario: Scenario | None,
    path: str | Path | None = None,
    overrides: Sequence[str] = (),
) -> tuple[dict[str, Any], Path, dict[str, Any]]:
    """The hyper-parameters of a run of ``algo`` on ``scenario``, validated.

    Layers, each checked on its own so that a message names where a bad value came from:

    1. the shipped defaults, ``configs/algos/<algo>.yaml``: its top-level keys (every scenario),
       then its section for the scenario, if any: a top-level key that is a scenario's name or
       env ID (``paper:`` or ``CaptureBench/Paper-v1:``, RL Zoo style) holding a mapping of
       hyper-parameters;
    2. ``path`` (``--config``), if given, the same way: its top-level keys, then its section
       for the scenario. A file may set a few keys; the others keep the shipped values;
    3. ``overrides``, ``KEY=VALUE`` strings (``--set``): VALUE is YAML, a dotted KEY reaches
       into ``policy_kwargs`` (``policy_kwargs.net_arch=[64,64]``).

    A later layer replaces an earlier one key by key (``policy_kwargs`` entry by entry).

    Returns:
        The validated mapping, the file it came from (``path``, else the shipped file), and
        where each layer came from: ``{"defaults": {"file": ..., "section": ...} or None (no
        --config), "file": ..., "section": name or None, "overrides": [...]}``.

    Raises:
        ConfigError: an unknown algorithm, file, key or section, or a bad value.
    """
    if algo not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {algo!r}; valid: {', '.join(ALGORITHMS)}")
    shipped = ALGO_DIR / f"{algo}.yaml"
    file = Path(path) if path is not None else shipped
    layered = path is not None and not _same_file(file, shipped)
    merged: dict[str, Any] = {}
    defaults = None
    if layered:
        top, section = _read_layers(shipped, algo, scenario)
        merged = _overlay(top, section[1]) if section else top
        defaults = {"file": str(shipped), "section": section[0] if section else None}
    top, chosen = _read_layers(file, algo, scenario)
    own = _overlay(top, chosen[1]) if chosen else top  # what the file and --set say
    for item in overrides:
        own = _overlay(own, parse_override(item, algo))
    merged = _overlay(merged, own)
    source = str(file) + (f" ({chosen[0]})" if chosen else "")
    shipped_features = layered and "features_extractor" not in own.get("policy_kwargs", {})
    hp = validate_hyperparameters(
        merged, algo, source, features_from=str(shipped) if shipped_features else None
    )
    origin = {
        "defaults": defaults,
        "file": str(file),
        "section": chosen[0] if chosen else None,
        "overrides": list(overrides),
    }
    return hp, file, origin


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve()
    except OSError:  # a path that cannot be resolved: reading it says why
        return False


def _read_layers(
    file: Path, algo: str, scenario: Scenario | None
) -> tuple[dict[str, Any], tuple[str, dict[str, Any]] | None]:
    """One hyper-parameter file, checked: its top-level keys, and its section for ``scenario``
    as ``(name, keys)`` (None: no scenario, or no section for it). Every section is checked,
    whichever scenario it is for."""
    if not is_file(file):
        raise ConfigError(f"{file}: no such hyper-parameter file")
    data, _ = read_mapping(file, "hyper-parameters")
    schema = _schema(algo)
    flat = {k: v for k, v in data.items() if k in schema}
    sections = {k: v for k, v in data.items() if k not in schema}
    names = _section_names(scenario)
    for key, section in sections.items():
        if not (isinstance(key, str) and key in names and isinstance(section, dict)):
            raise ConfigError(
                f"{file}: unknown key {shown(str(key))}; valid keys: {', '.join(schema)}, or a "
                f"scenario section ({', '.join(sorted(n for n in names if '/' not in n))} or "
                "an env ID) holding a mapping of hyper-parameters"
            )
        _check(section, schema, str(file), prefix=f"{key}.")
    chosen = (
        [] if scenario is None else [k for k in sections if k in (scenario.name, scenario.env_id)]
    )
    if len(chosen) > 1:
        assert scenario is not None
        raise ConfigError(
            f"{file}: two sections for scenario {scenario.name!r} ({chosen[0]!r} and "
            f"{chosen[1]!r}); keep one"
        )
    top = _check(flat, schema, str(file))
    if not chosen:
        return top, None
    return top, (chosen[0], _check(sections[chosen[0]], schema, str(file)))


def parse_override(item: Any, algo: str) -> dict[str, Any]:
    """One ``--set KEY=VALUE`` as a mapping checked like the file (``{"gamma": 0.98}``,
    ``{"policy_kwargs": {"net_arch": [64, 64]}}``).

    Raises:
        ConfigError: not KEY=VALUE, VALUE not YAML, an unknown key or a bad value; the
            message names the ``--set`` and what is valid.
    """
    source = f"--set {item}"
    if not isinstance(item, str) or "=" not in item or not item.split("=", 1)[0].strip():
        raise ConfigError(f"--set {item!r}: expected KEY=VALUE, e.g. --set learning_rate=1.0e-3")
    key, text = (part.strip() for part in item.split("=", 1))
    try:
        value = yaml.safe_load(text) if text else None
    except YAML_ERRORS as exc:
        first = " ".join(str(exc).split()) or type(exc).__name__
        raise ConfigError(f"{source}: the value is not valid YAML ({first})") from None
    if value is None:
        raise ConfigError(f"{source}: no value; expected KEY=VALUE, e.g. --set gamma=0.98")
    parts = key.split(".")
    if len(parts) > 2 or (len(parts) == 2 and parts[0] != "policy_kwargs"):
        raise ConfigError(
            f"{source}: key {shown(key)} is not valid; only policy_kwargs.<name> may be dotted"
        )
    data: dict[str, Any] = {parts[0]: value} if len(parts) == 1 else {parts[0]: {parts[1]: value}}
    return _check(data, _schema(algo), source)


def _overlay(base: dict[str, Any], layer: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``layer``'s keys replacing its own; ``policy_kwargs`` merged entry by entry."""
    out = {**base, **layer}
    if isinstance(layer.get("policy_kwargs"), dict):
        out["policy_kwargs"] = {**base.get("policy_kwargs", {}), **layer["policy_kwargs"]}
    return out


def _section_names(scenario: Scenario | None) -> set[str]:
    """What a scenario section may be called: a shipped scenario's name or env ID, or the
    run's own scenario's."""
    from capture_bench.task.scenarios import list_scenarios, load_scenario

    names: set[str] = set()
    for name in list_scenarios():
        names |= {name, load_scenario(name).env_id}
    if scenario is not None:
        names |= {scenario.name, scenario.env_id}
    return names


def sb3_kwargs(hp: dict[str, Any], algo: str) -> dict[str, Any]:
    """The validated hyper-parameters as keyword arguments of the SB3 algorithm's constructor.

    ``lin_<x>`` becomes a linear schedule from x to 0; ``activation_fn`` a torch module class;
    ``features_extractor`` SB3's ``features_extractor_class``;
    ``action_noise_std`` (TD3, DDPG) a `NormalActionNoise` on the 3 joints.
    """
    kwargs = {k: v for k, v in hp.items() if k in ALGO_KEYS[algo] and k != "action_noise_std"}
    for key in ("learning_rate", "clip_range"):
        if isinstance(kwargs.get(key), str):
            kwargs[key] = _linear(float(kwargs[key][4:]))
    policy_kwargs = dict(hp["policy_kwargs"])
    if "activation_fn" in policy_kwargs:
        import torch.nn

        policy_kwargs["activation_fn"] = getattr(
            torch.nn, ACTIVATIONS[policy_kwargs["activation_fn"]]
        )
    if "features_extractor" in policy_kwargs:
        from capture_bench.agents.features import FEATURE_EXTRACTORS

        name = policy_kwargs.pop("features_extractor")
        policy_kwargs["features_extractor_class"] = FEATURE_EXTRACTORS[name]
    kwargs["policy_kwargs"] = policy_kwargs
    if hp.get("action_noise_std"):
        from stable_baselines3.common.noise import NormalActionNoise

        kwargs["action_noise"] = NormalActionNoise(np.zeros(3), np.full(3, hp["action_noise_std"]))
    return kwargs


def pixel_env_options(hp: dict[str, Any]) -> dict[str, Any]:
    """The env keyword arguments of the pixel observation ``hp`` sets: ``image_size`` and the
    options of `PIXEL_OPTION_KEYS` it gives (none: the env's defaults)."""
    options = {key: hp[key] for key in PIXEL_OPTION_KEYS if hp.get(key) is not None}
    size = image_size(hp)
    return options if size is None else {"image_size": size, **options}


def image_size(hp: dict[str, Any]) -> tuple[int, int] | None:
    """The pixel observation's (width, height): ``image_size`` (square) where ``hp`` gives it,
    else None, the env's default (an env that does not observe pixels refuses a size)."""
    side = hp.get("image_size")
    return None if side is None else (side, side)


def _linear(initial: float) -> Any:
    def schedule(progress_remaining: float) -> float:
        """SB3 schedule: ``progress_remaining`` goes from 1 to 0 over training."""
        return progress_remaining * initial

    return schedule


def algorithm_class(algo: str) -> Any:
    """The SB3 (or sb3-contrib) class of ``algo``.

    Raises:
        ConfigError: ``algo`` is unknown, or its package (sb3-contrib for TQC) is not installed.
    """
    if algo not in ALGORITHM_CLASSES:
        raise ConfigError(f"unknown algorithm {algo!r}; valid: {', '.join(ALGORITHMS)}")
    module_name, name = ALGORITHM_CLASSES[algo]
    import importlib

    try:
        module = importlib.import_module(module_name)
    except ImportError:
        package = module_name.replace("_", "-")
        raise ConfigError(
            f"algorithm {algo} needs the package {package}: pip install {package}"
        ) from None
    return getattr(module, name)
