"""Agent specs: what ``--agents`` and suite files may name, resolved to agents.

A spec is one of:

* a built-in name (a key of [`capture_bench.agents.AGENTS`][capture_bench.agents.AGENTS], e.g.
``incremental_ik``);
* a trained model: a directory (a training run, or ``models/<name>``; ``<name>`` alone also finds
  ``models/<name>``) holding ``metadata.json``/``metadata.yaml`` and the policy, loaded without
  unpickling anything (an SB3 ``.zip`` only with ``trust_model``; see
  `capture_bench.agents.sb3_policy`); ``models/*`` expands to every model shipped;
* ``module:Class`` (or ``module:factory``): a user's agent following
  [`capture_bench.agents.Agent`][capture_bench.agents.Agent]. It is called with the environment's
  public
  `TaskDescription` if it takes one argument, with no argument if it takes none.

Specs are plain strings so they travel to worker processes and Ray tasks; each process resolves
them again and caches loaded SB3 models. Agents are rebuilt for every episode (construction is
cheap; loaded models are cached), and stochastic built-ins are seeded with the episode's seed, so
an episode's result does not depend on which process ran it or what it ran before.
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from capture_bench.evaluation.errors import AgentSpecError
from capture_bench.paths import SEEDS_DIR, models_dir

MODELS_DIR = models_dir()  # models/: see capture_bench.paths
MODELS_GLOB = "models/*"
#: Built-in agents whose constructor takes ``seed``; they get the episode's seed.
SEEDED_BUILTINS = frozenset({"random"})
#: Built-in agents whose actions never read the observation's target (random actions, the zero
#: action): what they are fed changes nothing, so they play no truth-fed twin.
BLIND_BUILTINS = frozenset({"random", "hold"})

_MODEL_CACHE: dict[tuple[str, bool], Any] = {}


@dataclass(frozen=True)
class AgentSpec:
    """A resolved agent spec.

    Attributes:
        spec: the string as given.
        label: the agent's name in reports.
        kind: ``builtin``, ``model`` or ``python``.
        target: the built-in name, the model directory (absolute) or ``module:attr``.
        privileged: the agent reads ground truth (the oracle): reported, not ranked.
        trust_model: a model may be loaded from an SB3 ``.zip`` (unpickled) where the directory
            has no safe form; the user opted in.
        image_size: (width, height) of the images a model that observes the camera's pixels
            sees (its episodes play in envs with ``observation_source="pixels"``); None for
            every agent that observes the estimate.
        pixel_options: such a model's pixel observation options (``(name, value)`` pairs of
            `capture_bench.sensing.workspace_image.PixelOptions`, those it changed; its card's
            ``pixel_observation``).
    """

    spec: str
    label: str
    kind: str
    target: str
    privileged: bool = False
    trust_model: bool = False
    image_size: tuple[int, int] | None = None
    pixel_options: tuple[tuple[str, int], ...] = ()

    def env_options(self) -> dict[str, Any]:
        """The env keyword arguments this agent's episodes play with (what it observes)."""
        from capture_bench.agents.sb3_policy import observation_options

        return observation_options(self.image_size, dict(self.pixel_options))


def builtin_names() -> list[str]:
    """Names of the built-in agents."""
    from capture_bench.agents import AGENTS

    return sorted(AGENTS)


def shipped_models(models_dir: Path = MODELS_DIR) -> list[str]:
    """Every model directory under ``models_dir`` (those holding a metadata file), sorted."""
    from capture_bench.agents.sb3_policy import find_metadata_file

    if not models_dir.is_dir():
        return []
    return sorted(
        str(p) for p in models_dir.iterdir() if p.is_dir() and find_metadata_file(p) is not None
    )


def expand_specs(specs: list[str], models_dir: Path = MODELS_DIR) -> list[str]:
    """Replace ``models/*`` by every shipped model directory whose model observes the estimate
    (a model that sees the camera's pixels renders an image every step, tens of times an
    estimate-fed step's work: it is named on its own, as the ``pixels`` suite does); drop
    duplicates, keep order."""
    out: list[str] = []
    glob: list[str] = []
    if MODELS_GLOB in specs:
        glob = [m for m in shipped_models(models_dir) if _model_kind(Path(m))[1] is None]
    for spec in specs:
        for item in glob if spec == MODELS_GLOB else [spec]:
            if item not in out:
                out.append(item)
    return out


def _valid_specs() -> str:
    return (
        f"valid: a built-in agent ({', '.join(builtin_names())}), a trained-model directory "
        "(models/<name> or a run directory with metadata.json), or module:Class"
    )


def resolve_agent(spec: str, models_dir: Path = MODELS_DIR, trust_model: bool = False) -> AgentSpec:
    """Resolve one spec (see module docstring); raises `AgentSpecError` if it names
    nothing. Models are not loaded here (see `check_agent`); ``trust_model`` lets a model
    directory without a safe form be loaded from its SB3 ``.zip`` (unpickling it)."""
    from capture_bench.agents import PRIVILEGED_AGENTS

    if spec in builtin_names():
        return AgentSpec(spec, spec, "builtin", spec, spec in PRIVILEGED_AGENTS)
    for candidate in (Path(spec), models_dir / spec):
        if candidate.is_dir():
            label = candidate.resolve().name
            if label in builtin_names():
                label = f"model:{label}"
            kind, image_size, options = _model_kind(candidate)
            return AgentSpec(
                spec, label + kind, "model", str(candidate.resolve()), False, trust_model,
                image_size, options,
            )  # fmt: skip
        if candidate.suffix == ".zip" and candidate.is_file():
            raise AgentSpecError(
                f"agent {spec!r}: name the model's directory ({candidate.parent}), which must "
                "also hold metadata.json"
            )
    if "/" in spec or spec.endswith(".zip"):
        raise AgentSpecError(f"agent {spec!r}: no such model directory; {_valid_specs()}")
    if ":" in spec:
        module_name, _, attr = spec.partition(":")
        try:
            module = importlib.import_module(module_name)
        except Exception as exc:
            raise AgentSpecError(f"agent {spec!r}: cannot import {module_name!r} ({exc})") from None
        factory = getattr(module, attr, None)
        if not callable(factory):
            raise AgentSpecError(f"agent {spec!r}: module {module_name!r} has no class {attr!r}")
        return AgentSpec(spec, spec, "python", spec, bool(getattr(factory, "privileged", False)))
    raise AgentSpecError(f"unknown agent {spec!r}; {_valid_specs()}")


@dataclass(frozen=True)
class TrainingSeeds:
    """The training seeds of a model shipped from several (its card's ``seeds``).

    Attributes:
        trained: every training seed, increasing.
        shipped: the seed whose policy is the model's own.
        specs: the agent spec (its policy's directory) of every other seed, by seed.
    """

    trained: tuple[int, ...]
    shipped: int
    specs: dict[int, str]


def training_seeds(spec: AgentSpec) -> TrainingSeeds | None:
    """The training seeds of ``spec``'s model, None where its card names none (or it is no
    model). Raises `AgentSpecError` where the card names a seed whose policy is missing."""
    if spec.kind != "model":
        return None
    from capture_bench.agents.sb3_policy import (
        PolicyLoadError,
        find_metadata_file,
        read_metadata_file,
    )

    meta_file = find_metadata_file(Path(spec.target))
    if meta_file is None:
        return None  # check_agent names it
    try:
        data = read_metadata_file(meta_file)
    except PolicyLoadError:
        return None  # too large or unreadable: check_agent names it
    card = data.get("model_card") if isinstance(data, dict) else None
    seeds = card.get("seeds") if isinstance(card, dict) else None
    if not seeds:
        return None
    try:
        trained = tuple(sorted(int(s) for s in seeds["trained"]))
        shipped = int(seeds["shipped"])
    except (KeyError, TypeError, ValueError):
        raise AgentSpecError(
            f"agent {spec.spec!r}: {meta_file}: model_card.seeds needs 'trained' (the training "
            "seeds) and 'shipped' (one of them)"
        ) from None
    specs = {s: str(Path(spec.target) / SEEDS_DIR / str(s)) for s in trained if s != shipped}
    missing = [p for p in specs.values() if find_metadata_file(Path(p)) is None]
    if shipped not in trained or missing:
        raise AgentSpecError(
            f"agent {spec.spec!r}: its card names training seeds {list(trained)}, shipped "
            f"{shipped}, but " + (f"{missing[0]} holds no policy" if missing else "not that one")
        )
    return TrainingSeeds(trained, shipped, specs)


def _model_kind(
    directory: Path,
) -> tuple[str, tuple[int, int] | None, tuple[tuple[str, int], ...]]:
    """What a model row says beside its name: `` (hybrid)`` for a residual on an analytic
    controller, `` (pixels)`` for a policy that sees the camera's image, `` (sampled)`` for a
    model card declaring sampled actions (nothing for the leaderboard's rule, deterministic
    actions); the size of the images it sees (None: it sees the estimate) and its pixel options.
    A bad metadata file is reported later."""
    from capture_bench.agents.policy_file import PolicyLoadError
    from capture_bench.agents.sb3_policy import read_metadata

    try:
        metadata = read_metadata(directory)
    except PolicyLoadError:
        return "", None, ()
    size = metadata.image_size
    sampled = metadata.actions == "sampled"
    words = [(metadata.residual, "hybrid"), (size, "pixels"), (sampled, "sampled")]
    options = tuple(sorted(metadata.pixel_options.items()))
    return "".join(f" ({word})" for flag, word in words if flag), size, options


def _python_factory(target: str) -> Any:
    module_name, _, attr = target.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def _call_user_factory(spec: AgentSpec, description: Any) -> Any:
    factory = _python_factory(spec.target)
    try:
        params = list(inspect.signature(factory).parameters.values())
    except (TypeError, ValueError):  # no signature (some builtins): call it with no argument
        params = []
    required = [
        p
        for p in params
        if p.default is inspect.Parameter.empty
        and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)
    ]
    if len(required) > 1:
        raise AgentSpecError(
            f"agent {spec.spec!r}: its constructor must take no argument or one (the "
            f"environment's TaskDescription); it requires {len(required)}"
        )
    return factory(description) if required else factory()


def _model(spec: AgentSpec) -> Any:
    """The loaded policy (`capture_bench.agents.sb3_policy.LoadedPolicy`), cached per
    process."""
    from capture_bench.agents.sb3_policy import load_policy, read_metadata

    key = (spec.target, spec.trust_model)
    if key not in _MODEL_CACHE:
        import torch

        # one observation at a time: intra-op threads only add overhead to a small MLP's
        # predict, and parallelism comes from the worker processes
        torch.set_num_threads(1)
        metadata = read_metadata(spec.target)
        _MODEL_CACHE[key] = load_policy(metadata, trust_model=spec.trust_model)
    return _MODEL_CACHE[key]


def declares_sampled_actions(spec: AgentSpec) -> bool:
    """Whether ``spec`` is a model whose card declares sampled actions (loads it, cached)."""
    return spec.kind == "model" and bool(_model(spec).sampled)


def build_agent(spec: AgentSpec, env: Any, seed: int) -> Any:
    """A fresh agent for one episode on ``env`` (seeded with ``seed`` if stochastic)."""
    if spec.kind == "builtin":
        from capture_bench.agents import make_agent

        extra = {"seed": seed} if spec.target in SEEDED_BUILTINS else {}
        return make_agent(spec.target, env, **extra)
    if spec.kind == "model":
        loaded = _model(spec)  # a residual's base is built from the env's public description
        description = env.unwrapped.description if loaded.residual is not None else None
        if loaded.sampled:  # declared sampled actions: reproducible, seeded per episode
            import torch

            torch.manual_seed(seed)
        return loaded.agent(spec.label, description, env)
    return _call_user_factory(spec, env.unwrapped.description)


def check_agent(spec: AgentSpec, env: Any, scenario: str) -> None:
    """Check at the edge that the agent can run on ``env`` (loads and checks a model's spaces;
    builds a user's agent and checks it follows the protocol)."""
    from capture_bench.agents.protocol import Agent

    if spec.kind == "model":
        from capture_bench.agents.sb3_policy import check_model_spaces

        check_model_spaces(_model(spec), env, f"{spec.spec} on {scenario}")
    elif spec.kind == "python":
        try:
            agent = _call_user_factory(spec, env.unwrapped.description)
        except AgentSpecError:
            raise
        except Exception as exc:
            raise AgentSpecError(f"agent {spec.spec!r}: construction failed ({exc})") from None
        if not isinstance(agent, Agent):
            raise AgentSpecError(
                f"agent {spec.spec!r}: needs predict(observation, state, episode_start, "
                "deterministic) and reset() (see capture_bench/agents/protocol.py)"
            )
