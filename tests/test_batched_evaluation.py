"""The leaderboard plays each agent's episodes together in the batched env, and its records are
the single env's: against a stored reference made by the single-env evaluation, against the
single env episode by episode, for a batch of episodes of different lengths, and for an agent
written for one observation at a time."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from capture_bench.agents import make_agent
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.evaluation.pipeline import EvaluationConfig, plan_evaluation
from capture_bench.evaluation.running.backends import EpisodeTask, run_task, run_tasks
from capture_bench.evaluation.running.rollout import TIMING_COLUMNS, run_episode, run_episodes
from capture_bench.task.scenarios import load_scenario

#: The default suite's episodes on the first two published seeds of every scenario, every agent,
#: each played in its own single ``CaptureEnv``, timing columns removed; the ``.json`` beside it
#: names the commit, machine and packages that made it. ``scripts/suite_reference.py`` adds an
#: agent's rows (``--rebuild``: every row, after a change of the rules).
_SPEC = importlib.util.spec_from_file_location(
    "suite_reference", Path(__file__).resolve().parent.parent / "scripts" / "suite_reference.py"
)
suite_reference = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(suite_reference)


def _same(value: object, expected: str) -> bool:
    """A record's value against the CSV's text: strings and whole numbers as written, floats
    bit for bit (the CSV holds their shortest round-trip repr), NaN (an empty cell) equal to
    NaN."""
    if isinstance(value, float):
        other = float(expected or "nan")
        return value == other or (math.isnan(value) and math.isnan(other))
    return str(value) == expected


def _differences(records, expected: dict) -> list[str]:
    out = []
    for record in records:
        row = expected[(record.agent, record.scenario, str(record.seed))]
        for column, value in record.as_row().items():
            if column not in TIMING_COLUMNS and not _same(value, row[column]):
                out.append(f"{record.agent} {record.scenario} {record.seed} {column}: {value!r}")
    return out


@pytest.fixture(scope="module")
def default_suite_records():
    """The default suite on two seeds of every scenario, every agent, through the evaluation's
    batched path, and the tasks."""
    plan = plan_evaluation(EvaluationConfig(suite="default", episodes=2, workers=1))
    return plan.tasks, run_tasks(plan.tasks)


def test_the_default_suites_episodes_equal_the_stored_reference(default_suite_records):
    """Every agent of the default suite (analytic, random, oracle, the shipped models and
    hybrids) on two seeds of every scenario, field for field, bit for bit, timing columns
    aside. Floats agree bit for bit only on the kind of machine that made the reference
    (docs/evaluation.md, Reproducibility); elsewhere the next test still holds the batched
    path to the single env."""
    made, expected = suite_reference.stored()
    there = suite_reference.fingerprint(made["machine"], made["packages"])
    here = suite_reference.this_machine()
    if here != there:
        pytest.skip(f"the reference was made on {there}; this machine is {here}")
    tasks, records = default_suite_records
    missing = suite_reference.missing_agents(tasks, expected)
    assert not missing, f"no reference rows for {missing}: run python scripts/suite_reference.py"
    assert {(r.agent, r.scenario, str(r.seed)) for r in records} == set(expected)
    assert _differences(records, expected) == []


def test_the_reference_names_an_agent_of_the_suite_it_has_no_rows_for(default_suite_records):
    """On any machine: every agent of the default suite has its rows in the reference, and an
    agent whose rows are gone is named (what ``scripts/suite_reference.py`` would add)."""
    tasks, _ = default_suite_records
    _, expected = suite_reference.stored()
    assert suite_reference.missing_agents(tasks, expected) == []
    assert len(expected) == len(tasks)
    without_hold = {key: row for key, row in expected.items() if key[0] != "hold"}
    assert suite_reference.missing_agents(tasks, without_hold) == ["hold"]


def test_adding_reference_rows_elsewhere_is_one_line_and_writes_nothing(monkeypatch, capsys):
    """Rows made on another kind of machine would differ in their last bits: the script refuses
    them before playing an episode and leaves the reference as it is."""
    made, expected = suite_reference.stored()
    before = suite_reference.REFERENCE.read_bytes()
    without_hold = {key: row for key, row in expected.items() if key[0] != "hold"}
    monkeypatch.setattr(suite_reference, "stored", lambda: (made, without_hold))
    monkeypatch.setattr(suite_reference, "this_machine", lambda: {"cpu_id": "another CPU"})
    with pytest.raises(SystemExit) as stop:
        suite_reference.main([])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "only on the reference's kind of machine" in err and "another CPU" in err
    assert suite_reference.REFERENCE.read_bytes() == before


def test_the_batched_evaluation_equals_the_single_env_on_every_agent(default_suite_records):
    """The same tasks, each played alone in a single ``CaptureEnv`` (the oracle's path, and
    the evaluation's before it was batched), give the same records on any machine."""
    tasks, records = default_suite_records
    single = [run_task(task)[0] for task in tasks[::2]]  # the first seed of each
    assert records[::2] == single


class OneAtATime:
    """A user's agent written for one observation: ``predict`` refuses a batch, and it counts
    its steps (state a batched call would mix up between episodes)."""

    def __init__(self, description) -> None:
        self.inner = make_agent("pure_pursuit", _Holder(description))
        self.steps = 0

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        assert np.asarray(observation).shape == (16,), "one observation at a time"
        self.steps += 1
        action = self.inner.act(observation) if self.steps > 2 else np.zeros(3, np.float32)
        return action, state

    def reset(self) -> None:
        self.steps = 0


class _Holder:
    def __init__(self, description) -> None:
        self.unwrapped = self
        self.description = description


def test_an_agent_that_handles_one_observation_still_evaluates():
    """Built once per episode (the documented fallback), each instance asked with its own
    episode's observation; the records equal the single env's."""
    seeds = load_scenario("drift").evaluation_seeds[:4]
    tasks = [EpisodeTask(f"{__name__}:OneAtATime", "drift", seed) for seed in seeds]
    batched = run_tasks(tasks)
    single = [run_task(task)[0] for task in tasks]
    assert batched == single  # timing columns are not compared
    assert any(r.captured for r in batched)


class _IntoTheFloor:
    """Swings the arm down into the floor: a collision after a few steps."""

    batched = False

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.array([1.0, -1.0, -1.0], dtype=np.float32), state

    def reset(self) -> None:
        pass


def test_episodes_of_different_lengths_in_one_batch_end_with_the_right_records():
    """One batch: a capture, a collision, a timeout (hold), and the same seed twice; each
    record equals the single env's for its seed and agent, and a second run of the batch
    (its target sides replayed from the env's cache) gives the same records again."""
    vector = CaptureVectorEnv(4, "paper", autoreset_mode=AutoresetMode.DISABLED)
    single = CaptureEnv("paper", reuse_target_side=True)
    seeds = [1_000_000, 1_000_001, 1_000_003, 1_000_000]
    agents = [
        make_agent("incremental_ik", single),
        _IntoTheFloor(),
        make_agent("hold", single),
        make_agent("incremental_ik", single),
    ]
    first = run_episodes(vector, agents, agent_name="mixed", scenario="paper", seeds=seeds)
    again = run_episodes(vector, agents, agent_name="mixed", scenario="paper", seeds=seeds)
    expected = [
        run_episode(single, agent, agent_name="mixed", scenario="paper", seed=seed)[0]
        for agent, seed in zip(agents, seeds, strict=True)
    ]
    vector.close()
    single.close()
    assert first == expected and again == expected
    assert [(r.outcome, r.failure) for r in first] == [
        ("captured", ""),
        ("failed", "collision"),
        ("failed", "timeout"),
        ("captured", ""),
    ]
    assert len({r.steps for r in first}) == 3


def test_one_batched_agent_needs_batched_true():
    vector = CaptureVectorEnv(2, "paper", autoreset_mode=AutoresetMode.DISABLED)
    with pytest.raises(ValueError, match="not batched"):
        run_episodes(vector, _IntoTheFloor(), agent_name="floor", scenario="paper", seeds=[1, 2])
    with pytest.raises(ValueError, match="1 agents for 2 episodes"):
        run_episodes(vector, [_IntoTheFloor()], agent_name="floor", scenario="paper", seeds=[1, 2])
    vector.close()


def _observations(per_scenario: int = 200) -> np.ndarray:
    """Observations the evaluation meets: pure pursuit and random moves in four scenarios."""
    out = []
    rng = np.random.default_rng(0)
    for scenario in ("paper", "grasp", "evasive", "tumbling"):
        env = CaptureVectorEnv(8, scenario)
        obs, _ = env.reset(seed=5)
        agent = make_agent("pure_pursuit", env)
        for _ in range(per_scenario // 8):
            moves = rng.uniform(-1, 1, (8, 3))
            obs, *_ = env.step(agent.predict(obs)[0] if rng.random() < 0.7 else moves)
            out.append(obs.copy())
        env.close()
    return np.concatenate(out)


#: Runs of the kinds no shipped model is (a SAC policy, gSDE as on paper; a PPO residual on
#: incremental_ik, a hybrid): train.py's configs, their networks as shipped, a few steps each.
TINY_RUNS = {
    "sac": ["--algo", "sac", "--set", "n_envs=2", "--set", "total_timesteps=64",
            "--set", "learning_starts=32", "--set", "batch_size=32", "--set", "buffer_size=1000"],
    "residual": ["--algo", "ppo", "--set", "residual=incremental_ik", "--set", "n_envs=2",
                 "--set", "total_timesteps=64", "--set", "n_steps=32", "--set", "batch_size=32",
                 "--set", "n_epochs=1"],
}  # fmt: skip


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory) -> Path:
    """``TINY_RUNS``' run directories, trained on paper, without validation or checkpoints."""
    import train

    root = tmp_path_factory.mktemp("tiny_runs")
    quiet = ["--set", "eval_freq=0", "--set", "checkpoint_freq=0", "--device", "cpu"]
    for name, argv in TINY_RUNS.items():
        assert train.main([*argv, *quiet, "--run-dir", str(root / name)]) == 0
    return root


@pytest.mark.parametrize("name", ["models/dagger-dls-paper", "models/dagger-dls-all", *TINY_RUNS])
def test_a_models_batch_of_rows_equals_each_row_alone(name, request):
    """``predict_rows`` (one forward pass, row-exact layers) against ``predict`` on each
    observation alone, bit for bit: what lets the evaluation batch a model's episodes. The
    shipped PPO models, and a SAC policy and a hybrid trained here."""
    from capture_bench.evaluation.running.agents_loading import build_agent, resolve_agent

    if name in TINY_RUNS:
        name = str(request.getfixturevalue("tiny_runs") / name)
    agent = build_agent(resolve_agent(name), CaptureEnv("paper"), 0)
    obs = _observations()
    alone = np.stack([agent.predict(row)[0] for row in obs])
    np.testing.assert_array_equal(agent.predict_rows(obs), alone)
    np.testing.assert_array_equal(agent.predict_rows(obs[:1]), alone[:1])


@pytest.mark.parametrize(("inputs", "outputs"), [(20, 128), (128, 128), (128, 3), (64, 1)])
def test_a_row_exact_layer_gives_each_row_its_own_result(inputs, outputs):
    """On rows the probe never saw; and where no batched form is found, rows one by one."""
    import torch

    from capture_bench.agents import row_exact

    torch.manual_seed(1)
    layer = torch.nn.Linear(inputs, outputs)
    x = torch.randn(300, inputs)
    with torch.no_grad():
        alone = torch.cat([layer(x[i : i + 1]) for i in range(len(x))])
        with row_exact.row_exact_layers(layer) as exact:
            assert exact
            batched = layer(x)
        assert torch.equal(batched, alone)
        assert "forward" not in vars(layer)  # restored


def test_a_model_without_row_exact_layers_acts_row_by_row(monkeypatch):
    import weakref

    from capture_bench.agents import row_exact
    from capture_bench.evaluation.running.agents_loading import build_agent, resolve_agent

    monkeypatch.setattr(row_exact, "row_exact_forward", lambda layer: None)
    monkeypatch.setattr(row_exact, "_LAYERS", weakref.WeakKeyDictionary())
    agent = build_agent(resolve_agent("models/dagger-dls-paper"), CaptureEnv("paper"), 0)
    obs = _observations(40)
    alone = np.stack([agent.predict(row)[0] for row in obs])
    one_by_one = []
    monkeypatch.setattr(agent, "_deterministic_action", lambda row: one_by_one.append(row) or 0)
    assert agent.predict_rows(obs).shape == (len(obs),)  # the stand-in's zeros, row by row
    assert len(one_by_one) == len(obs)
    monkeypatch.undo()
    np.testing.assert_array_equal(agent.predict_rows(obs), alone)


def test_a_recording_the_single_env_made_is_replayed_by_the_batched_env():
    """Shared recordings go both ways: a seed the single env recorded (with its bound, kept
    by seed in the cache) is replayed by the batched env, and the episode is the same."""
    from capture_bench.engine.cache import EpisodeCache

    cache = EpisodeCache()
    single = CaptureEnv("paper", reuse_target_side=True, episode_cache=cache)
    single.reset(seed=1_000_004)
    (key,) = cache.recorded_keys()
    assert cache.recording(key)[0].bound is not None  # every recording carries its bound
    vector = CaptureVectorEnv(
        1,
        "paper",
        autoreset_mode=AutoresetMode.DISABLED,
        episode_cache=cache,
    )
    agent = make_agent("incremental_ik", single)
    (batched,) = run_episodes(vector, agent, agent_name="ik", scenario="paper", seeds=[1_000_004])
    assert cache.counts()[0] == 1  # replayed, not recorded again
    alone, _ = run_episode(single, agent, agent_name="ik", scenario="paper", seed=1_000_004)
    assert batched == alone
    vector.close()
    single.close()


@pytest.mark.parametrize("scenario", ["jitter", "grasp"])
def test_a_sub_envs_view_reads_what_the_single_env_reads(scenario):
    """The oracle plays in the batched env through each sub-env's view of the privileged API:
    at every step it gives the single env's time, next period, bound and true target."""
    seeds = [7_000_003, 7_000_004]
    vector = CaptureVectorEnv(2, scenario, autoreset_mode=AutoresetMode.DISABLED)
    singles = [CaptureEnv(scenario, reuse_target_side=True) for _ in seeds]
    try:
        obs, _ = vector.reset(seed=seeds)
        for env, seed in zip(singles, seeds, strict=True):
            env.reset(seed=seed)
        views = [vector.sub_env(i) for i in range(2)]
        agents = [make_agent("oracle", view) for view in views]
        assert views[0].unwrapped is views[0] and views[0].description is vector.description
        for _ in range(5):
            actions = np.zeros((2, 3))
            for i, (view, env) in enumerate(zip(views, singles, strict=True)):
                assert view.time == env.time
                assert view.next_control_period == env.next_control_period
                assert view.physical_limit().time == env.physical_limit().time
                t = view.time + 0.01
                assert np.array_equal(view.true_target_position(t), env.true_target_position(t))
                actions[i] = agents[i].act(obs[i])
            obs = vector.step(actions)[0]
            for i, env in enumerate(singles):
                env.step(actions[i].astype(np.float32))
    finally:
        vector.close()
        for env in singles:
            env.close()
    with pytest.raises(IndexError):
        vector.sub_env(2)
