"""scripts/landing_phase.py: the approach ends at the first step within ``near`` of the capture
point and the landing lasts from there to the capture, as the env's own ``info`` says."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.task.scenarios import load_scenario

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "landing_phase.py"


def _script():
    spec = importlib.util.spec_from_file_location("landing_phase", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_phases_are_the_first_step_within_near_and_the_capture_time():
    landing_phase = _script()
    scenario = load_scenario("paper")
    seed = scenario.validation_seeds[0]
    env = CaptureEnv(scenario)
    agent = make_agent("joint_intercept_dls", env)
    approach, capture = landing_phase.phases(env, agent, seed, 0.03)
    obs, _ = env.reset(seed=seed)  # the same episode again, step by step
    times, done = [], False
    while not done:
        obs, _, terminated, truncated, info = env.step(agent.predict(obs)[0])
        times.append((info["time"], info["distance"]))
        done = terminated or truncated
    env.close()
    assert approach == next(t for t, d in times if d < 0.03)
    assert capture == info["capture_time"] and approach < capture
    never, _ = landing_phase.phases(CaptureEnv(scenario), make_agent("hold", env), seed, 1e-6)
    assert math.isnan(never)


def test_an_unknown_agent_is_one_line(capsys):
    assert _script().main(["no_such_agent", "--seeds", "1"]) == 2
    err = capsys.readouterr().err
    assert "unknown agent 'no_such_agent'" in err and len(err.strip().splitlines()) == 1
