"""Per-algorithm hyper-parameters: ``configs/algos/<algo>.yaml`` (RL-Zoo-like keys), validated once.

An unknown key or a bad value raises :class:`~capture_bench.task.scenarios.ConfigError` naming the
file, the key, the value and what is valid; :func:`sb3_kwargs` turns a validated mapping into the
SB3 algorithm's constructor arguments. No SB3 or torch import happens at module level.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from capture_bench.task.scenarios import CONFIG_DIR
from capture_bench.validation import ConfigError, Rule, Schema, check_mapping, is_file, read_mapping

ALGO_DIR = CONFIG_DIR / "algos"
ALGORITHMS = ("ppo", "sac", "td3")
OFF_POLICY = ("sac", "td3")
ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU"}


# Counts SB3 and numpy hold as machine integers: at most 2**53 (exact as a float, fits an int64).
MOST = 2**53
POS_INT, NONNEG_INT = Rule("int", 1, MOST), Rule("int", 0, MOST)
UNIT, NONNEG = Rule("float", 0.0, 1.0), Rule("float", 0.0)
TRAINING_KEYS = {
    "n_envs": POS_INT,
    "total_timesteps": POS_INT,
    "policy": Rule("choice", choices=("MlpPolicy",)),
    "policy_kwargs": Rule("mapping"),
    "normalize": Rule("bool"),
    "reward": Rule("choice", choices=("dense", "sparse")),
    "checkpoint_freq": NONNEG_INT,
    "eval_freq": NONNEG_INT,
    "eval_episodes": POS_INT,
}
_COMMON = {"learning_rate": Rule("schedule"), "gamma": UNIT, "batch_size": POS_INT}
_OFF = {
    **_COMMON,
    "buffer_size": POS_INT,
    "learning_starts": NONNEG_INT,
    "tau": UNIT,
    "train_freq": POS_INT,
    "gradient_steps": Rule("int", -1),
}
ALGO_KEYS: dict[str, dict[str, Rule]] = {
    "ppo": {
        **_COMMON,
        "n_steps": Rule("int", 2),
        "n_epochs": POS_INT,
        "gae_lambda": UNIT,
        "clip_range": Rule("schedule"),
        "ent_coef": NONNEG,
        "vf_coef": NONNEG,
        "max_grad_norm": NONNEG,
        "use_sde": Rule("bool"),
        "sde_sample_freq": Rule("int", -1),
        "target_kl": Rule("optional_float", 0.0),
        "normalize_advantage": Rule("bool"),
    },
    "sac": {
        **_OFF,
        "ent_coef": Rule("float_or_auto"),
        "target_update_interval": POS_INT,
        "target_entropy": Rule("float_or_auto"),
        "use_sde": Rule("bool"),
        "sde_sample_freq": Rule("int", -1),
        "use_sde_at_warmup": Rule("bool"),
    },
    "td3": {
        **_OFF,
        "policy_delay": POS_INT,
        "target_policy_noise": NONNEG,
        "target_noise_clip": NONNEG,
        "action_noise_std": NONNEG,  # Gaussian exploration noise, in action units (Box(-1, 1))
    },
}
POLICY_KWARGS = {
    "net_arch": Rule("layers", choices=("pi", "vf", "qf")),  # qf for sac/td3
    "activation_fn": Rule("choice", choices=tuple(ACTIVATIONS)),
    "log_std_init": Rule("float"),
    "ortho_init": Rule("bool"),
    "n_critics": POS_INT,
}


def validate_hyperparameters(data: Any, algo: str, source: str) -> dict[str, Any]:
    """Check a hyper-parameter mapping for ``algo``; return it with numbers in canonical form.

    Raises:
        ConfigError: not a mapping, an unknown key, or a bad value (the message names
            ``source``, the key, the value and what is valid).
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of hyper-parameters, got {data!r}")
    schema: Schema = {**TRAINING_KEYS, **ALGO_KEYS[algo], "policy_kwargs": POLICY_KWARGS}
    required = dict.fromkeys(("n_envs", "total_timesteps"), POS_INT.describe())
    out = check_mapping(data, schema, source, required=required)
    out.setdefault("policy", "MlpPolicy")
    out.setdefault("policy_kwargs", {})
    out.setdefault("normalize", False)
    out.setdefault("reward", "dense")
    out.setdefault("checkpoint_freq", 0)
    out.setdefault("eval_freq", 0)
    out.setdefault("eval_episodes", 5)
    return out


def load_hyperparameters(algo: str, path: str | Path | None = None) -> tuple[dict[str, Any], Path]:
    """Read and validate ``configs/algos/<algo>.yaml`` (or ``path``); return it and its path."""
    if algo not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {algo!r}; valid: {', '.join(ALGORITHMS)}")
    file = Path(path) if path is not None else ALGO_DIR / f"{algo}.yaml"
    if not is_file(file):
        raise ConfigError(f"{file}: no such hyper-parameter file")
    data, _ = read_mapping(file, "hyper-parameters")
    return validate_hyperparameters(data, algo, str(file)), file


def sb3_kwargs(hp: dict[str, Any], algo: str) -> dict[str, Any]:
    """The validated hyper-parameters as keyword arguments of the SB3 algorithm's constructor.

    ``lin_<x>`` becomes a linear schedule from x to 0; ``activation_fn`` a torch module class;
    ``action_noise_std`` (TD3) a :class:`NormalActionNoise` on the 3 joints.
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
    kwargs["policy_kwargs"] = policy_kwargs
    if hp.get("action_noise_std"):
        from stable_baselines3.common.noise import NormalActionNoise

        kwargs["action_noise"] = NormalActionNoise(np.zeros(3), np.full(3, hp["action_noise_std"]))
    return kwargs


def _linear(initial: float) -> Any:
    def schedule(progress_remaining: float) -> float:
        """SB3 schedule: ``progress_remaining`` goes from 1 to 0 over training."""
        return progress_remaining * initial

    return schedule
