"""What ``tune.py`` samples for each algorithm: one table, `SAMPLERS`, after the RL Zoo's
``rl_zoo3/hyperparams_opt.py`` (the same names, mostly the same ranges).

Each entry maps an Optuna parameter name to a `Param`: its distribution and the
hyper-parameter key (of ``configs/algos/<algo>.yaml``) it sets. A sample is merged over the base
YAML and validated by `validate_hyperparameters`,
so a sample can never be an invalid config (``tests/test_tune.py`` checks every space). Adding an
algorithm is adding an entry here. No Optuna import happens here: the table is plain data.

Differences from the Zoo, and why: ``learning_starts`` is sampled as a share of the per-trial
budget (the Zoo's fixed 0-20000 steps would leave a short trial nothing to learn from); the
off-policy learning rate stops at 1e-2 (the Zoo's upper bound 1 only diverges); TD3's exploration
noise is Gaussian (``action_noise_std``, 0 = none), the only kind our configs declare; A2C's
and TQC's are the Zoo's ``sample_a2c_params`` / ``sample_tqc_params`` less the learning-rate
schedule; DDPG samples TD3's space.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Choice:
    """One of ``values`` (Optuna's ``suggest_categorical``)."""

    values: tuple[Any, ...]


@dataclass(frozen=True)
class Uniform:
    """A number in [low, high], uniform or (``log``) log-uniform (Optuna's ``suggest_float``)."""

    low: float
    high: float
    log: bool = False


def _same(value: Any, budget: int) -> Any:
    return value


@dataclass(frozen=True)
class Param:
    """One sampled hyper-parameter.

    Args:
        space: its distribution.
        key: the hyper-parameter it sets, dotted for nested keys (``policy_kwargs.net_arch``).
        convert: ``(sampled value, per-trial budget in environment steps) -> the key's value``.
        also: further keys set to the same value (the Zoo ties ``gradient_steps`` to
            ``train_freq``).
    """

    space: Choice | Uniform
    key: str
    convert: Callable[[Any, int], Any] = _same
    also: tuple[str, ...] = ()


def _one_minus(value: float, budget: int) -> float:
    return 1.0 - value


def _share_of_budget(value: float, budget: int) -> int:
    return int(value * budget)


def _networks(table: dict[str, Any]) -> Callable[[str, int], Any]:
    def convert(name: str, budget: int) -> Any:
        return table[name]

    return convert


PPO_NETS = {
    "tiny": {"pi": [64], "vf": [64]},
    "small": {"pi": [64, 64], "vf": [64, 64]},
    "medium": {"pi": [256, 256], "vf": [256, 256]},
}
OFF_POLICY_NETS = {"small": [64, 64], "medium": [256, 256], "big": [400, 300]}
GAMMAS = (0.9, 0.95, 0.98, 0.99, 0.995, 0.999)
TAUS = (0.001, 0.005, 0.01, 0.02, 0.05, 0.08)
TRAIN_FREQS = (1, 4, 8, 16, 32, 64)  # vector-env steps between updates (gradient_steps: the same)

_OFF_POLICY: dict[str, Param] = {
    "gamma": Param(Choice(GAMMAS), "gamma"),
    "learning_rate": Param(Uniform(1e-5, 1e-2, log=True), "learning_rate"),
    "batch_size": Param(Choice((64, 128, 256, 512, 1024)), "batch_size"),
    "buffer_size": Param(Choice((10_000, 100_000, 1_000_000)), "buffer_size"),
    "learning_starts_share": Param(
        Choice((0.0, 0.01, 0.05, 0.1)), "learning_starts", _share_of_budget
    ),
    "train_freq": Param(Choice(TRAIN_FREQS), "train_freq", also=("gradient_steps",)),
    "tau": Param(Choice(TAUS), "tau"),
    "net_arch": Param(
        Choice(tuple(OFF_POLICY_NETS)), "policy_kwargs.net_arch", _networks(OFF_POLICY_NETS)
    ),
}

#: algorithm -> Optuna parameter name -> `Param`.
SAMPLERS: dict[str, dict[str, Param]] = {
    "ppo": {
        "batch_size": Param(Choice((32, 64, 128, 256, 512)), "batch_size"),
        "n_steps": Param(Choice((32, 64, 128, 256, 512, 1024, 2048)), "n_steps"),
        "one_minus_gamma": Param(Uniform(1e-4, 0.03, log=True), "gamma", _one_minus),
        "one_minus_gae_lambda": Param(Uniform(1e-4, 0.1, log=True), "gae_lambda", _one_minus),
        "learning_rate": Param(Uniform(1e-5, 2e-3, log=True), "learning_rate"),
        "ent_coef": Param(Uniform(1e-8, 0.1, log=True), "ent_coef"),
        "clip_range": Param(Choice((0.1, 0.2, 0.3, 0.4)), "clip_range"),
        "n_epochs": Param(Choice((1, 5, 10, 20)), "n_epochs"),
        "max_grad_norm": Param(Uniform(0.3, 2.0), "max_grad_norm"),
        "net_arch": Param(Choice(tuple(PPO_NETS)), "policy_kwargs.net_arch", _networks(PPO_NETS)),
        "activation_fn": Param(Choice(("tanh", "relu")), "policy_kwargs.activation_fn"),
    },
    "a2c": {
        "n_steps": Param(Choice((8, 16, 32, 64, 128, 256, 512)), "n_steps"),
        "one_minus_gamma": Param(Uniform(1e-4, 0.03, log=True), "gamma", _one_minus),
        "one_minus_gae_lambda": Param(Uniform(1e-4, 0.1, log=True), "gae_lambda", _one_minus),
        "learning_rate": Param(Uniform(1e-5, 2e-3, log=True), "learning_rate"),
        "ent_coef": Param(Uniform(1e-8, 0.1, log=True), "ent_coef"),
        "vf_coef": Param(Uniform(0.0, 1.0), "vf_coef"),
        "max_grad_norm": Param(Uniform(0.3, 5.0), "max_grad_norm"),
        "normalize_advantage": Param(Choice((False, True)), "normalize_advantage"),
        "use_rms_prop": Param(Choice((False, True)), "use_rms_prop"),
        "ortho_init": Param(Choice((False, True)), "policy_kwargs.ortho_init"),
        "net_arch": Param(Choice(tuple(PPO_NETS)), "policy_kwargs.net_arch", _networks(PPO_NETS)),
        "activation_fn": Param(Choice(("tanh", "relu")), "policy_kwargs.activation_fn"),
    },
    "sac": dict(_OFF_POLICY),
    "td3": {**_OFF_POLICY, "action_noise_std": Param(Uniform(0.0, 1.0), "action_noise_std")},
    "ddpg": {**_OFF_POLICY, "action_noise_std": Param(Uniform(0.0, 1.0), "action_noise_std")},
    "tqc": {
        **_OFF_POLICY,
        "top_quantiles_to_drop_per_net": Param(
            Choice((0, 1, 2, 3, 4, 5)), "top_quantiles_to_drop_per_net"
        ),
        "n_quantiles": Param(Choice((5, 10, 25, 50)), "policy_kwargs.n_quantiles"),
    },
}


def suggest(trial: Any, name: str, space: Choice | Uniform) -> Any:
    """Ask the Optuna ``trial`` for parameter ``name`` from ``space``."""
    if isinstance(space, Choice):
        return trial.suggest_categorical(name, space.values)
    return trial.suggest_float(name, space.low, space.high, log=space.log)


def sample(trial: Any, algo: str, budget: int, keep: tuple[str, ...] = ()) -> dict[str, Any]:
    """The hyper-parameters the ``trial`` samples for ``algo``: dotted key -> value.

    Args:
        trial: an Optuna trial (anything with ``suggest_categorical`` and ``suggest_float``).
        algo: a key of `SAMPLERS`.
        budget: the per-trial budget, environment steps (``learning_starts`` is a share of it).
        keep: parameter names not sampled (their keys keep the base YAML's value).
    """
    out: dict[str, Any] = {}
    for name, param in SAMPLERS[algo].items():
        if name in keep:
            continue
        value = param.convert(suggest(trial, name, param.space), budget)
        for key in (param.key, *param.also):
            out[key] = value
    return out


def describe_space(algo: str, budget: int, keep: tuple[str, ...] = ()) -> dict[str, str]:
    """What ``algo``'s trials of ``budget`` steps sample, less ``keep``, as a study stores it:
    parameter name -> its distribution, the keys it sets and, where converted, what each choice
    becomes (``"Choice(values=(64, 128)) -> batch_size"``)."""
    out = {}
    for name, param in SAMPLERS[algo].items():
        if name in keep:
            continue
        text = f"{param.space!r} -> {', '.join((param.key, *param.also))}"
        if param.convert is not _same and isinstance(param.space, Choice):
            text += f" = {[param.convert(value, budget) for value in param.space.values]}"
        elif param.convert is not _same:
            text += f" via {param.convert.__name__}"
        out[name] = text
    return out


def merge(base: dict[str, Any], sampled: dict[str, Any]) -> dict[str, Any]:
    """``base`` (a hyper-parameter mapping, not modified) with the dotted keys of ``sampled``
    set."""
    out = copy.deepcopy(base)
    for dotted, value in copy.deepcopy(sampled).items():
        *parents, key = dotted.split(".")
        node = out
        for parent in parents:
            node = node.setdefault(parent, {})
        node[key] = value
    return out
