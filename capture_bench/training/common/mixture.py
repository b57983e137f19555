"""Training on a mixture of scenarios: one policy for every scenario.

``train.py --scenario all`` (every shipped scenario) or ``--scenario paper,tumbling,grasp`` trains
one policy on all of them at once: the ``n_envs`` sub-envs are split between the scenarios
(evenly, or by the ``mixture_weights`` hyper-parameter: `mixture_shares`), each share a
batched env of its scenario
(`CaptureSB3VecEnv`) on that scenario's training
seeds, and `MixtureVecEnv` puts them side by side as one SB3 ``VecEnv``. The periodic
validation plays ``eval_episodes`` validation seeds of every scenario and pools them (each
scenario weighs the same), and logs each scenario's capture rate too. The observation carries no
scenario label: the policy must act from what it sees, as on the leaderboard, where it is
evaluated on each scenario.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from capture_bench.task.scenarios import ConfigError, Scenario, list_scenarios, load_scenario

#: The scenario spec that names every shipped scenario.
ALL = "all"


def is_mixture(spec: str) -> bool:
    """Whether a ``--scenario`` names a mixture (``all`` or a comma-separated list)."""
    return spec == ALL or "," in spec


def mixture_scenarios(spec: str) -> list[Scenario]:
    """The scenarios of a ``--scenario`` spec: one, every shipped ranked one with the analytic
    camera (``all``: what the leaderboard ranks; ``paper_eq20``, the paper's own rule, is not
    one), or a comma-separated list (each a name or a YAML path).

    Raises:
        ConfigError: an unknown scenario, an empty or repeated name.
    """
    names = (
        [name for name in list_scenarios(camera="analytic") if load_scenario(name).ranked]
        if spec == ALL
        else [part.strip() for part in spec.split(",")]
    )
    if any(not name for name in names):
        raise ConfigError(
            f"--scenario {spec!r}: an empty name in the list; expected names separated by commas"
        )
    scenarios = [load_scenario(name) for name in names]
    seen = [s.name for s in scenarios]
    repeated = sorted({n for n in seen if seen.count(n) > 1})
    if repeated:
        raise ConfigError(f"--scenario {spec!r}: scenario {repeated[0]!r} named twice")
    return scenarios


def mixture_shares(
    n_envs: int, names: Sequence[str], weights: dict[str, float] | None = None
) -> list[int]:
    """How many of the ``n_envs`` sub-envs each scenario of a mixture gets, in ``names``' order.

    Without ``weights``, an equal share each (``n_envs`` must be a multiple of the count). With
    ``weights`` (scenario name -> weight > 0; a scenario left out weighs 1), shares in proportion
    to the weights, rounded by the largest remainder (ties to the earlier scenario), so they sum
    to ``n_envs``: of 64 sub-envs and 8 scenarios, ``{"grasp": 7}`` gives grasp 32 and each other
    scenario 4 or 5 (64 / 14 each, about 4.6).

    Raises:
        ConfigError: uneven without weights, a weight for a scenario not in the mixture, or a
            scenario left with no sub-env.
    """
    count = len(names)
    if not weights:
        if n_envs % count:
            up = count * -(-n_envs // count)
            raise ConfigError(
                f"n_envs {n_envs} does not split evenly between {count} scenarios; use a "
                f"multiple of {count} (e.g. --n-envs {up}), or give mixture_weights"
            )
        return [n_envs // count] * count
    unknown = sorted(set(weights) - set(names))
    if unknown:
        raise ConfigError(
            f"mixture_weights names {unknown[0]!r}, which is not in the mixture; valid: "
            + ", ".join(names)
        )
    w = np.array([float(weights.get(name, 1.0)) for name in names])
    exact = n_envs * w / w.sum()
    shares = np.floor(exact).astype(int)
    order = sorted(range(count), key=lambda k: (-(exact[k] - shares[k]), k))
    for k in order[: n_envs - int(shares.sum())]:
        shares[k] += 1
    if shares.min() < 1:
        empty = names[int(np.argmin(shares))]
        need = int(np.ceil(w.sum() / w.min()))
        raise ConfigError(
            f"mixture_weights leave scenario {empty!r} no sub-env of n_envs {n_envs}; use more "
            f"sub-envs (e.g. --n-envs {need}) or closer weights"
        )
    return shares.tolist()


def mixture_name(spec: str) -> str:
    """A name for run directories and model cards: ``all``, or the names joined by ``+``."""
    return ALL if spec == ALL else "+".join(s.name for s in mixture_scenarios(spec))


class MixtureVecEnv(VecEnv):
    """Several SB3 ``VecEnv``s with the same spaces as one: sub-env i of the mixture is sub-env
    i - offset of the part that holds it. ``seed(s)`` seeds part k with ``s + offset_k`` (SB3's
    rule for sub-env i: ``s + i``, kept across the parts).

    Args:
        parts: the vector envs, in order (they are closed with the mixture).
    """

    def __init__(self, parts: Sequence[VecEnv]) -> None:
        if not parts:
            raise ValueError("MixtureVecEnv needs at least one vector env")
        first = parts[0]
        for part in parts[1:]:
            if (
                part.observation_space != first.observation_space
                or part.action_space != first.action_space
            ):
                raise ValueError("MixtureVecEnv: every part must have the same spaces")
        self.parts = list(parts)
        self.offsets = np.cumsum([0] + [p.num_envs for p in self.parts]).tolist()
        super().__init__(self.offsets[-1], first.observation_space, first.action_space)

    def reset(self) -> Any:
        for k, part in enumerate(self.parts):
            seed = self._seeds[self.offsets[k]]
            if seed is not None:
                part.seed(seed)
        self._reset_seeds()
        obs = np.concatenate([part.reset() for part in self.parts])
        self.reset_infos = [info for part in self.parts for info in part.reset_infos]
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        for k, part in enumerate(self.parts):
            part.step_async(actions[self.offsets[k] : self.offsets[k + 1]])

    def step_wait(self) -> VecEnvStepReturn:
        results = [part.step_wait() for part in self.parts]
        self.reset_infos = [info for part in self.parts for info in part.reset_infos]
        return (
            np.concatenate([r[0] for r in results]),
            np.concatenate([r[1] for r in results]),
            np.concatenate([r[2] for r in results]),
            [info for r in results for info in r[3]],
        )

    def close(self) -> None:
        for part in self.parts:
            part.close()

    def _route(self, indices: VecEnvIndices) -> list[tuple[VecEnv, list[int]]]:
        """(part, its local indices) for the mixture's ``indices``, in order."""
        wanted = list(self._get_indices(indices))
        routed = []
        for k, part in enumerate(self.parts):
            local = [
                i - self.offsets[k] for i in wanted if self.offsets[k] <= i < self.offsets[k + 1]
            ]
            if local:
                routed.append((part, local))
        return routed

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [v for part, local in self._route(indices) for v in part.get_attr(attr_name, local)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for part, local in self._route(indices):
            part.set_attr(attr_name, value, local)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs
    ) -> list[Any]:
        return [
            v
            for part, local in self._route(indices)
            for v in part.env_method(method_name, *method_args, indices=local, **method_kwargs)
        ]

    def env_is_wrapped(self, wrapper_class: Any, indices: VecEnvIndices = None) -> list[bool]:
        return [
            v
            for part, local in self._route(indices)
            for v in part.env_is_wrapped(wrapper_class, local)
        ]
