"""capture-bench: robotic capture of a moving, non-cooperative target (Dong & Zhu 2016).

Importing the package registers one gymnasium environment per shipped scenario,
``CaptureBench/<Name>-v1`` (``gymnasium.make("CaptureBench/Paper-v1")``), with a batched vector
env (``gymnasium.make_vec("CaptureBench/Paper-v1", num_envs=64)``,
`capture_bench.envs.vector_env`).

An invalid file under ``configs/scenarios/`` breaks only itself: importing never raises or prints
because of it, every valid scenario is registered, and the file's error (file, key, what is valid)
is raised as [`ConfigError`][capture_bench.ConfigError] when it is used: ``load_scenario(name)``, or
``gymnasium.make("CaptureBench/<Stem>-v1")`` (its ID is registered from the file name, since the
file cannot be trusted to name itself). ``python -m capture_bench list`` shows both kinds.
"""

from __future__ import annotations

from gymnasium import error
from gymnasium.envs.registration import register, registry

from capture_bench.task.scenarios import (
    ConfigError,
    invalid_scenarios,
    list_scenarios,
    load_scenario,
    scenario_files,
)

__version__ = "0.1.0"
__all__ = ["ConfigError", "env_ids", "invalid_scenarios", "list_scenarios", "load_scenario"]


def env_ids() -> list[str]:
    """The registered environment IDs, one per valid shipped scenario."""
    return [load_scenario(name).env_id for name in list_scenarios()]


def _register() -> None:
    for path in scenario_files():
        try:
            env_id = load_scenario(path).env_id
        except ConfigError:  # registered under its file name; gym.make raises the file's error
            env_id = f"CaptureBench/{path.stem.title().replace('_', '')}-v1"
        if env_id in registry:
            continue
        try:  # No TimeLimit: the env truncates itself at the scenario's limit in simulated seconds.
            register(
                id=env_id,
                entry_point="capture_bench.envs.capture_env:CaptureEnv",
                vector_entry_point="capture_bench.envs.vector_env:CaptureVectorEnv",
                kwargs={"scenario": path.stem},
            )
        except error.Error:  # a name gymnasium cannot use as an ID; load_scenario(name) still works
            continue


_register()
