"""Per-algorithm hyper-parameters: ``configs/algos/<algo>.yaml`` (RL-Zoo-like keys), validated once.

An unknown key or a bad value raises :class:`~capture_bench.task.scenarios.ConfigError` naming the
file, the key, the value and what is valid; :func:`sb3_kwargs` turns a validated mapping into the
SB3 algorithm's constructor arguments. No SB3 or torch import happens at module level.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from capture_bench.task.scenarios import CONFIG_DIR, ConfigError

ALGO_DIR = CONFIG_DIR / "algos"
ALGORITHMS = ("ppo", "sac", "td3")
OFF_POLICY = ("sac", "td3")
ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU"}


@dataclass(frozen=True)
class Rule:
    """How one YAML key is validated: ``kind`` and, for numbers, the range [low, high]."""

    kind: str  # int, float, bool, choice, schedule, float_or_auto, optional_float, mapping
    low: float = -math.inf
    high: float = math.inf
    choices: tuple[str, ...] = ()

    def describe(self) -> str:
        if self.kind == "choice":
            return "one of " + ", ".join(self.choices)
        bounded = math.isfinite(self.low) or math.isfinite(self.high)
        rng = f" in [{self.low:g}, {self.high:g}]" if bounded else ""
        text = {
            "int": "a whole number",
            "float": "a number",
            "bool": "true or false",
            "schedule": "a number > 0 or 'lin_<number>' (linear decay to 0)",
            "float_or_auto": "a number, 'auto' or 'auto_<number>'",
            "optional_float": "a number or null",
            "mapping": "a mapping",
        }[self.kind]
        return text + (rng if self.kind in ("int", "float", "optional_float") else "")


POS_INT, NONNEG_INT = Rule("int", 1), Rule("int", 0)
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
    "net_arch": Rule("mapping"),  # list of layer widths, or {pi: [...], vf|qf: [...]}
    "activation_fn": Rule("choice", choices=tuple(ACTIVATIONS)),
    "log_std_init": Rule("float"),
    "ortho_init": Rule("bool"),
    "n_critics": POS_INT,
}


def _check(value: Any, rule: Rule, where: str) -> Any:
    """Validate one value against its rule; return it in canonical form."""
    bad = ConfigError(f"{where}: {value!r} is not valid; expected {rule.describe()}")
    kind = rule.kind
    if kind == "bool":
        if not isinstance(value, bool):
            raise bad
        return value
    if kind == "choice":
        if value not in rule.choices:
            raise bad
        return value
    if kind == "optional_float" and value is None:
        return None
    if kind in ("schedule", "float_or_auto") and isinstance(value, str) and not _is_number(value):
        prefix = "lin_" if kind == "schedule" else "auto"
        rest = value[len(prefix) :].lstrip("_")
        if not value.startswith(prefix) or (rest and not _is_number(rest)):
            raise bad
        if kind == "schedule" and (not rest or float(rest) <= 0):
            raise bad
        return value
    if isinstance(value, bool) or not _is_number(value):
        raise bad
    number = float(value)  # YAML reads 3e-4 (no dot) as a string; accept it as the number it is
    if kind == "int":
        if not number.is_integer():
            raise bad
        number = int(number)
    low = 0.0 if kind == "schedule" else rule.low
    if not (math.isfinite(number) and low <= number <= rule.high) or (
        kind == "schedule" and number <= 0
    ):
        raise bad
    return number


def _is_number(value: Any) -> bool:
    try:
        float(value)
    except (TypeError, ValueError):
        return False
    return not isinstance(value, bool)


def _check_net_arch(value: Any, where: str) -> Any:
    def layers(v: Any) -> bool:
        return isinstance(v, list) and all(isinstance(n, int) and n > 0 for n in v)

    if layers(value):
        return value
    if (
        isinstance(value, dict)
        and value
        and all(k in ("pi", "vf", "qf") and layers(v) for k, v in value.items())
    ):
        return value
    raise ConfigError(
        f"{where}: {value!r} is not valid; expected a list of layer widths like [64, 64] "
        "or a mapping {pi: [...], vf: [...]} (qf for sac/td3)"
    )


def validate_hyperparameters(data: Any, algo: str, source: str) -> dict[str, Any]:
    """Check a hyper-parameter mapping for ``algo``; return it with numbers in canonical form.

    Raises:
        ConfigError: not a mapping, an unknown key, or a bad value (the message names
            ``source``, the key, the value and what is valid).
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of hyper-parameters, got {data!r}")
    rules = {**TRAINING_KEYS, **ALGO_KEYS[algo]}
    out: dict[str, Any] = {}
    for key, value in data.items():
        if key not in rules:
            raise ConfigError(
                f"{source}: unknown key {key!r} for {algo}; valid keys: {', '.join(rules)}"
            )
        where = f"{source}: key {key!r}"
        if key == "policy_kwargs":
            if not isinstance(value, dict):
                raise ConfigError(f"{where}: {value!r} is not valid; expected a mapping")
            kwargs = {}
            for sub, sub_value in value.items():
                if sub not in POLICY_KWARGS:
                    raise ConfigError(
                        f"{source}: unknown key 'policy_kwargs.{sub}'; "
                        f"valid keys: {', '.join(POLICY_KWARGS)}"
                    )
                sub_where = f"{source}: key 'policy_kwargs.{sub}'"
                kwargs[sub] = (
                    _check_net_arch(sub_value, sub_where)
                    if sub == "net_arch"
                    else _check(sub_value, POLICY_KWARGS[sub], sub_where)
                )
            out[key] = kwargs
        else:
            out[key] = _check(value, rules[key], where)
    for key in ("n_envs", "total_timesteps"):
        if key not in out:
            raise ConfigError(f"{source}: missing key {key!r} (a whole number >= 1)")
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
    if not file.is_file():
        raise ConfigError(f"{file}: no such hyper-parameter file")
    try:
        data = yaml.safe_load(file.read_text())
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0] if str(exc) else "parse error"
        raise ConfigError(f"{file}: invalid YAML ({first})") from None
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
