"""Agents for capture-bench: the paper's controller, classic baselines and the privileged oracle.

Every agent follows [`capture_bench.agents.protocol.Agent`][capture_bench.agents.protocol.Agent]
(SB3-style ``predict`` plus ``reset``) and acts in the shared action space ``Box(-1, 1, (3,))``.
Build one by name with [`make_agent`][capture_bench.agents.make_agent]; the names, what each
agent does and what it sees are [`AGENTS`][capture_bench.agents.AGENTS]'s table.

Analytic agents are built from ``env.unwrapped.description`` (a
[`capture_bench.task.observation.TaskDescription`][capture_bench.task.observation.TaskDescription])
and nothing else; only the oracle keeps a
reference to the environment, and it carries ``privileged = True``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from capture_bench.agents.base import AnalyticController
from capture_bench.agents.baselines import (
    DampedLeastSquares,
    Hold,
    Intercept,
    JointIntercept,
    JointInterceptDLS,
    PurePursuit,
    RandomAgent,
)
from capture_bench.agents.incremental_ik import FOLLOW_THROUGH, IncrementalIK, incremental_steps
from capture_bench.agents.oracle import Oracle
from capture_bench.agents.planned_intercept import PlannedIntercept
from capture_bench.agents.protocol import Agent

AgentFactory = Callable[..., Agent]


def _public(cls: Callable[..., Agent], **defaults: Any) -> AgentFactory:
    """Factory that hands the agent the environment's public description only."""

    def factory(env: Any, **kwargs: Any) -> Agent:
        return cls(env.unwrapped.description, **{**defaults, **kwargs})

    factory.__doc__ = f"Build {cls.__name__} from ``env.unwrapped.description`` only."
    return factory


def _oracle(env: Any, **kwargs: Any) -> Agent:
    """Build the privileged oracle from the environment itself."""
    return Oracle(env, **kwargs)


AGENTS: dict[str, AgentFactory] = {
    "incremental_ik": _public(IncrementalIK),
    "incremental_ik_uncapped": _public(IncrementalIK, cap=False),
    "incremental_ik_through": _public(IncrementalIK, follow_through=FOLLOW_THROUGH),
    "pure_pursuit": _public(PurePursuit),
    "intercept": _public(Intercept),
    "joint_intercept": _public(JointIntercept),
    "joint_intercept_uncapped": _public(JointIntercept, cap=False),
    "dls": _public(DampedLeastSquares),
    "joint_intercept_dls": _public(JointInterceptDLS),
    "planned_intercept": _public(PlannedIntercept),
    "random": _public(RandomAgent),
    "hold": _public(Hold),
    "oracle": _oracle,
}
"""The built-in agents by name, as [`make_agent`][capture_bench.agents.make_agent] takes them;
each value is a factory, ``AGENTS[name](env, **kwargs)``, that builds the agent for ``env``. All but
the oracle see only the environment's public description and the observations; the oracle sees the
environment itself (privileged, ranked apart).

- `incremental_ik`: [`IncrementalIK`][capture_bench.agents.incremental_ik.IncrementalIK], Dong &
  Zhu (2016) eqs. 13-19, λ_max, with the step cap.
- `incremental_ik_uncapped`: the same, paper-exact (``cap=False``).
- `incremental_ik_through`: the same, its capped step aiming 2 mm past X_T' (``follow_through``).
- `pure_pursuit`: [`PurePursuit`][capture_bench.agents.baselines.PurePursuit], straight at the
  estimate X^_T, no look-ahead.
- `intercept`: [`Intercept`][capture_bench.agents.baselines.Intercept], straight at the predicted
  interception point.
- `joint_intercept`: [`JointIntercept`][capture_bench.agents.baselines.JointIntercept], each joint
  to the earliest pose that meets the prediction.
- `joint_intercept_uncapped`: the same at full rate, sweeping through that pose (``cap=False``).
- `dls`: [`DampedLeastSquares`][capture_bench.agents.baselines.DampedLeastSquares], damped least
  squares resolved rate, feed-forward + P.
- `joint_intercept_dls`: [`JointInterceptDLS`][capture_bench.agents.baselines.JointInterceptDLS],
  `joint_intercept` far from the estimate, `dls` within 30 mm of it.
- `planned_intercept`:
  [`PlannedIntercept`][capture_bench.agents.planned_intercept.PlannedIntercept], the oracle's
  landing and tracking on the estimate's constant-velocity trajectory, planned again as the
  estimate moves.
- `random`: [`RandomAgent`][capture_bench.agents.baselines.RandomAgent], uniform random actions
  (seeded).
- `hold`: [`Hold`][capture_bench.agents.baselines.Hold], zero action.
- `oracle`: [`Oracle`][capture_bench.agents.oracle.Oracle], "oracle (privileged)" in reports: to
  the physical-limit pose, knowing the true target.
"""

PRIVILEGED_AGENTS = frozenset({"oracle"})


def make_agent(name: str, env: Any, **kwargs: Any) -> Agent:
    """Build the agent registered as ``name`` for ``env``.

    Args:
        name: a key of [`AGENTS`][capture_bench.agents.AGENTS].
        env: a capture-bench environment (or a wrapper of one).
        **kwargs: passed to the agent's constructor (e.g. ``cap=False``, ``seed=3``).

    Raises:
        ValueError: for an unknown name; the message lists the valid ones.
    """
    try:
        factory = AGENTS[name]
    except KeyError:
        valid = ", ".join(sorted(AGENTS))
        raise ValueError(f"unknown agent {name!r}; valid agents: {valid}") from None
    return factory(env, **kwargs)


__all__ = [
    "AGENTS",
    "PRIVILEGED_AGENTS",
    "Agent",
    "AgentFactory",
    "AnalyticController",
    "DampedLeastSquares",
    "Hold",
    "IncrementalIK",
    "Intercept",
    "Oracle",
    "PlannedIntercept",
    "PurePursuit",
    "RandomAgent",
    "incremental_steps",
    "make_agent",
]
