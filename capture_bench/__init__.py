"""capture-bench: robotic capture of a moving, non-cooperative target (Dong & Zhu 2016).

Importing the package registers one gymnasium environment per shipped scenario,
``CaptureBench/<Name>-v0`` (``gymnasium.make("CaptureBench/Paper-v0")``), with a batched vector
env (``gymnasium.make_vec("CaptureBench/Paper-v0", num_envs=64)``, :mod:`capture_bench.vector_env`).
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from capture_bench.scenarios import ConfigError, list_scenarios, load_scenario

__version__ = "0.1.0"
__all__ = ["ConfigError", "env_ids", "list_scenarios", "load_scenario"]


def env_ids() -> list[str]:
    """The registered environment IDs, one per shipped scenario."""
    return [load_scenario(name).env_id for name in list_scenarios()]


def _register() -> None:
    for name in list_scenarios():
        env_id = load_scenario(name).env_id
        if env_id not in registry:
            # No TimeLimit: the env truncates itself at the scenario's limit in simulated seconds.
            register(
                id=env_id,
                entry_point="capture_bench.env:CaptureEnv",
                vector_entry_point="capture_bench.vector_env:CaptureVectorEnv",
                kwargs={"scenario": name},
            )


_register()
