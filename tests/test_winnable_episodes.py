"""Every drawn episode can be won: its physical limit is finite before the time limit.

``draw_plans`` (``capture_bench/task/episode.py``) keeps a seed's first plan where its bound is
finite and otherwise draws again from the seed's own generator. Here: every published seed of
every ranked scenario has a finite bound; a seed that needed a redraw gets the same redrawn
episode in the single env and the vector env, every time; and a seed whose first plan was
winnable keeps it, generator state and all.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pytest
from gymnasium.utils import seeding

from capture_bench.engine.cache import EpisodeCache
from capture_bench.engine.task import CaptureTask, scenario_camera
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.task import episode as episode_module
from capture_bench.task.episode import (
    EpisodePlan,
    describe_task,
    draw_periods,
    draw_plans,
    episode_bounds,
    place_target,
)
from capture_bench.task.scenarios import Scenario, list_scenarios, load_scenario

#: The shipped scenarios with the analytic camera: the ranked ones, and any other among them.
ANALYTIC = list_scenarios(camera="analytic")
SAMPLE_TIMES = np.linspace(0.0, 5.0, 11)  # s: where two trajectories are compared


@dataclass
class PublishedDraws:
    """One scenario's published seeds: each seed's first plan (trajectory, then periods, from
    its generator, no rule) and its bound, the plan ``draw_plans`` keeps, and the generators'
    states after each."""

    scenario: Scenario
    seeds: list[int]
    first: list[EpisodePlan]
    first_bounds: list[float]
    first_states: list[dict]
    kept: list[EpisodePlan]
    kept_states: list[dict]

    @property
    def redrawn(self) -> list[int]:
        """Indices of the seeds whose first plan has no finite bound."""
        return [i for i, t in enumerate(self.first_bounds) if not math.isfinite(t)]


def _first_plan(scenario: Scenario, seed: int) -> tuple[EpisodePlan, dict]:
    camera, features = scenario_camera(scenario)
    rng = seeding.np_random(seed)[0]
    trajectory = place_target(scenario, camera.model, features, rng)
    plan = EpisodePlan(scenario, trajectory, draw_periods(scenario.control, rng))
    return plan, rng.bit_generator.state


def _same_plan(a: EpisodePlan, b: EpisodePlan) -> bool:
    return np.array_equal(a.periods, b.periods) and np.array_equal(
        a.trajectory.position(SAMPLE_TIMES), b.trajectory.position(SAMPLE_TIMES)
    )


@pytest.fixture(scope="module")
def published() -> dict[str, PublishedDraws]:
    out = {}
    for name in ANALYTIC:
        scenario = load_scenario(name)
        seeds = scenario.evaluation_seeds
        firsts = [_first_plan(scenario, seed) for seed in seeds]
        first = [plan for plan, _ in firsts]
        bounds = episode_bounds(first, describe_task(scenario))
        camera, features = scenario_camera(scenario)
        rngs = [seeding.np_random(seed)[0] for seed in seeds]
        kept = draw_plans(scenario, camera.model, features, rngs)
        out[name] = PublishedDraws(
            scenario,
            seeds,
            first,
            [b.time for b in bounds],
            [state for _, state in firsts],
            kept,
            [rng.bit_generator.state for rng in rngs],
        )
    return out


def test_the_ranked_scenarios_are_among_those_tested():
    ranked = {"circular", "drift", "evasive", "grasp", "jitter", "noisy", "paper", "tumbling"}
    assert ranked <= set(ANALYTIC)


def test_every_published_seed_of_every_ranked_scenario_has_a_finite_bound(published):
    """The bound of each kept plan, computed again from its trajectory and periods alone (the
    env's description; the carried bound dropped), is finite and is the one the plan carries."""
    for name, draws in published.items():
        bare = [dataclasses.replace(plan, bound=None) for plan in draws.kept]
        bounds = episode_bounds(bare, describe_task(draws.scenario))
        for seed, plan, bound in zip(draws.seeds, draws.kept, bounds, strict=True):
            assert math.isfinite(bound.time), f"{name} seed {seed}: bound {bound.time}"
            assert bound.time <= plan.end(), f"{name} seed {seed}"
            assert plan.bound is not None and plan.bound.time == bound.time, (name, seed)
            np.testing.assert_array_equal(plan.bound.theta, bound.theta)


def test_a_first_plan_with_a_finite_bound_is_kept_unchanged(published):
    """The rule changes no winnable episode: the same trajectory, periods and generator state
    (so the camera's noise after it too), and the carried bound is the first plan's."""
    kept = 0
    for name, draws in published.items():
        redrawn = set(draws.redrawn)
        for i, seed in enumerate(draws.seeds):
            if i in redrawn:
                continue
            assert _same_plan(draws.first[i], draws.kept[i]), f"{name} seed {seed} changed"
            assert draws.kept_states[i] == draws.first_states[i], f"{name} seed {seed}"
            assert draws.kept[i].bound.time == draws.first_bounds[i], f"{name} seed {seed}"
            kept += 1
    assert kept >= 0.9 * sum(len(d.seeds) for d in published.values())


def test_a_seed_whose_first_plan_cannot_be_won_gets_another_episode(published):
    """Some published seeds' first plans have no finite bound (the target leaves the arm's
    reach first); each is replaced by a later plan of its own generator, with a finite bound."""
    redrawn = [(name, i) for name, draws in published.items() for i in draws.redrawn]
    assert redrawn, "no published seed needs a redraw: this test no longer tests the rule"
    for name, i in redrawn:
        draws = published[name]
        seed, first, kept = draws.seeds[i], draws.first[i], draws.kept[i]
        assert not _same_plan(first, kept), f"{name} seed {seed} kept its unwinnable plan"
        assert draws.kept_states[i] != draws.first_states[i], f"{name} seed {seed}"
        assert math.isfinite(kept.bound.time), f"{name} seed {seed}"
        # The redraw continues the seed's generator: the second plan of the same stream.
        rng = seeding.np_random(seed)[0]
        camera, features = scenario_camera(draws.scenario)
        for _ in range(2):
            trajectory = place_target(draws.scenario, camera.model, features, rng)
            periods = draw_periods(draws.scenario.control, rng)
            plan = EpisodePlan(draws.scenario, trajectory, periods)
            (bound,) = episode_bounds([plan], describe_task(draws.scenario))
            if math.isfinite(bound.time):
                break
        assert _same_plan(plan, kept), f"{name} seed {seed}: not its generator's next plan"


def _redrawn_seed(published: dict[str, PublishedDraws]) -> tuple[str, int, int]:
    """A scenario, one of its published seeds that needed a redraw, and one that did
    not."""
    for name, draws in published.items():
        if draws.redrawn:
            i = draws.redrawn[0]
            j = next(j for j in range(len(draws.seeds)) if j not in draws.redrawn)
            return name, draws.seeds[i], draws.seeds[j]
    pytest.fail("no published seed needs a redraw")


@pytest.mark.parametrize("reuse_target_side", [False, True])
def test_the_single_env_plays_the_redrawn_episode_every_time(published, reuse_target_side):
    """``CaptureEnv.reset(seed=s)`` twice (nothing kept between the two: a fresh cache each)
    gives the kept plan of s, its target side and its bound."""
    name, seed, _ = _redrawn_seed(published)
    kept = published[name].kept[published[name].seeds.index(seed)]
    sides = []
    for _ in range(2):
        env = CaptureEnv(name, reuse_target_side=reuse_target_side, episode_cache=EpisodeCache())
        env.reset(seed=seed)
        assert _same_plan(env.plan, kept)
        assert env.physical_limit().time == kept.bound.time
        sides.append(env.recorded_episode)  # row 0 filled (every row when recorded)
        env.close()
    np.testing.assert_array_equal(sides[0].position[:1], sides[1].position[:1])
    np.testing.assert_array_equal(sides[0].images[:1], sides[1].images[:1])


@pytest.mark.parametrize("shared_cache", [False, True])
def test_the_vector_env_plays_the_single_envs_redrawn_episode_every_time(published, shared_cache):
    """``CaptureVectorEnv.reset(seed=[...])`` twice, a redrawn seed and a kept one, in an env
    with its own cache or a shared one: the kept plans, the single env's true states and frames,
    the same bounds."""
    name, redrawn, unchanged = _redrawn_seed(published)
    draws = published[name]
    seeds = [redrawn, unchanged]
    singles = []
    for seed in seeds:
        env = CaptureEnv(name, reuse_target_side=True, episode_cache=EpisodeCache())
        env.reset(seed=seed)
        singles.append((env.recorded_episode, env.physical_limit()))
        env.close()
    for _ in range(2):
        cache = EpisodeCache() if shared_cache else None  # else its own, new
        vec = CaptureVectorEnv(2, name, episode_cache=cache)
        vec.reset(seed=seeds)
        for i, seed in enumerate(seeds):
            view = vec.sub_env(i)
            assert _same_plan(view.plan, draws.kept[draws.seeds.index(seed)]), seed
            single, bound = singles[i]
            assert view.physical_limit().time == bound.time
            np.testing.assert_array_equal(view.recorded_episode.position, single.position)
            np.testing.assert_array_equal(view.recorded_episode.images, single.images)
        vec.close()


def test_the_drawn_bound_is_the_envs_own():
    """The bound a plan carries is computed for the task its env publishes (so the env reuses
    it, not computed again); a plan asked for another task's bound gets that task's, computed."""
    for name in ANALYTIC:
        scenario = load_scenario(name)
        env_task = CaptureTask(scenario).description
        assert episode_module._same_task(env_task, describe_task(scenario)), name
    scenario = load_scenario("paper")
    camera, features = scenario_camera(scenario)
    (plan,) = draw_plans(scenario, camera.model, features, [seeding.np_random(0)[0]])
    assert episode_bounds([plan], CaptureTask(scenario).description)[0] is plan.bound
    wider = dataclasses.replace(describe_task(scenario), capture_tolerance=np.full(3, 0.05))
    (bound,) = episode_bounds([plan], wider)
    (recomputed,) = episode_bounds([dataclasses.replace(plan, bound=None)], wider)
    assert bound.time == recomputed.time < plan.bound.time


def test_a_scenario_with_no_winnable_episode_fails_loudly(monkeypatch):
    """After ``MAX_PLAN_DRAWS`` plans with no finite bound, ``RuntimeError`` names the
    scenario."""
    monkeypatch.setattr(episode_module, "MAX_PLAN_DRAWS", 3)
    scenario = load_scenario("paper").replace(capture={"hold": 0.0}, control={"episode_limit": 0.1})
    camera, features = scenario_camera(scenario)
    with pytest.raises(RuntimeError, match="scenario 'paper': no episode the arm can win"):
        draw_plans(scenario, camera.model, features, [seeding.np_random(0)[0]])


def test_an_episodes_bound_is_computed_once(published, monkeypatch):
    """The bound computed to keep a plan is the one the env reports at the episode's end: one
    computation per plan drawn (two for a seed drawn twice), none after."""
    calls = []
    original = episode_module.physical_limits

    def counted(target_positions, *args, **kwargs):
        calls.append(len(target_positions))
        return original(target_positions, *args, **kwargs)

    monkeypatch.setattr(episode_module, "physical_limits", counted)
    name, redrawn, unchanged = _redrawn_seed(published)
    for seed, draws in ((unchanged, 1), (redrawn, 2)):
        calls.clear()
        env = CaptureEnv(name, episode_cache=EpisodeCache())
        env.reset(seed=seed)
        assert env.physical_limit().time == env.plan.bound.time
        env.close()
        assert calls == [1] * draws, seed
