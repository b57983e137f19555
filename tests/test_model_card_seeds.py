"""A model shipped from several training seeds: its card names the seeds and the one shipped
(the median validation score, on validation seeds only), each seed's policy is in
``seeds/<seed>/``, and runs that differ in more than the seed, or repeat one, are refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

import train
from capture_bench.task.scenarios import ConfigError, load_scenario
from capture_bench.training.train import model_card
from capture_bench.training.train.model_card import SEEDS_HEADING, median_seed, ship_seeds

TINY = ["n_envs=2", "n_steps=32", "batch_size=32", "n_epochs=1", "total_timesteps=64",
        "policy_kwargs.net_arch=[8]"]  # fmt: skip
SEEDS = (7, 3, 5)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> list[Path]:
    """Three tiny PPO runs on ``paper`` that differ only in their training seed."""
    root = tmp_path_factory.mktemp("runs")
    dirs = []
    for seed in SEEDS:
        run_dir = root / f"seed{seed}"
        args = [*(f"--set={s}" for s in TINY), "--seed", str(seed), "--run-dir", str(run_dir)]
        assert train.main(args) == 0
        dirs.append(run_dir)
    return dirs


def _card(target: Path) -> dict:
    return json.loads((target / "metadata.json").read_text())["model_card"]


def test_three_seeds_ship_as_one_model_whose_card_names_them(runs, tmp_path):
    target = ship_seeds(runs, "tiny3", episodes=2, out=tmp_path / "models")
    card = _card(target)
    seeds = card["seeds"]
    assert seeds["trained"] == sorted(SEEDS)
    assert seeds["selection"] == "median validation score (validation seeds)"
    scores = {int(s): v for s, v in seeds["scores"].items()}
    assert seeds["shipped"] == median_seed(scores) and card["training_seed"] == seeds["shipped"]
    for seed in SEEDS:
        assert sorted(p.name for p in (target / "seeds" / str(seed)).iterdir()) == [
            "metadata.json",
            "policy.pt",
        ]
        summary = seeds["validation"][str(seed)]["paper"]
        assert summary["seeds"] == list(load_scenario("paper").validation_seeds[:2])
    shipped = runs[SEEDS.index(seeds["shipped"])]
    assert (target / "policy.pt").read_bytes() == (shipped / "policy.pt").read_bytes()
    readme = (target / "README.md").read_text()
    assert SEEDS_HEADING in readme and f"The policy shipped is seed {seeds['shipped']}'s" in readme
    assert all(f"| {s}" in readme for s in SEEDS)
    assert not list(tmp_path.joinpath("models").glob(".tmp-*"))


def test_the_median_validation_score_ships_and_no_published_seed_is_played(
    runs, tmp_path, monkeypatch
):
    """Validation replaced by known scores (seed 7: 0.9, seed 3: 0.2, seed 5: 0.4): seed 5,
    the median, ships; every seed played is a validation seed, none a published one."""
    known = {7: 0.9, 3: 0.2, 5: 0.4}
    played: list[int] = []

    def validate(model_dir, scenario, seeds):
        played.extend(seeds)
        score = known[int(Path(model_dir).name)]
        episodes = [{"seed": s, "captured": True, "capture_time": 1.0} for s in seeds]
        return {"seeds": seeds, "episodes": episodes, "capture_rate": 1.0,
                "median_ratio_to_limit": 1 / score, "median_capture_time": 1.0,
                "mean_score": score}  # fmt: skip

    monkeypatch.setattr(model_card, "validate_policy", validate)
    card = _card(ship_seeds(runs, "known", episodes=3, out=tmp_path))
    assert card["seeds"]["shipped"] == 5 and card["training_seed"] == 5
    scenario = load_scenario("paper")
    assert played and set(played) <= set(scenario.validation_seeds)
    assert not set(played) & set(scenario.evaluation_seeds)


def test_the_median_seed_breaks_ties_by_the_lower_seed():
    assert median_seed({1: 0.5, 2: 0.1, 3: 0.9}) == 1
    assert median_seed({4: 0.5, 2: 0.5, 3: 0.9}) == 2
    assert median_seed({1: 0.2, 2: 0.2, 3: 0.2}) == 1
    assert median_seed({1: 0.1, 2: 0.2, 3: 0.3, 4: 0.4}) == 2  # the lower middle one


def _altered(run: Path, where: Path, seed: int, hyperparameter: dict | None = None) -> Path:
    """A copy of ``run`` trained with seed ``seed`` (and other hyper-parameters)."""
    shutil.copytree(run, where, ignore=shutil.ignore_patterns("tb", "checkpoints"))
    config = json.loads((where / "config.json").read_text())
    config["config"]["seed"] = seed
    config["hyperparameters"] |= hyperparameter or {}
    (where / "config.json").write_text(json.dumps(config))
    meta = json.loads((where / "metadata.json").read_text())
    meta["seed"] = seed
    meta["command"] = meta["command"].replace(f"--seed {SEEDS[0]}", f"--seed {seed}")
    (where / "metadata.json").write_text(json.dumps(meta))
    return where


def test_runs_that_differ_in_a_hyperparameter_or_repeat_a_seed_are_refused_in_one_line(
    runs, tmp_path, capsys
):
    other = _altered(runs[0], tmp_path / "other", 11, {"learning_rate": 0.001})
    models = tmp_path / "models"
    with pytest.raises(ConfigError, match="hyper-parameter learning_rate: 0.0003 in .*0.001 in"):
        ship_seeds([runs[0], runs[1], other], "bad", episodes=2, out=models)
    with pytest.raises(ConfigError, match=f"repeat training seed {SEEDS[0]}"):
        ship_seeds([runs[0], runs[1], runs[0]], "bad", episodes=2, out=models)
    assert not models.exists() or not any(models.iterdir())  # nothing written
    same = _altered(runs[0], tmp_path / "same", 11)  # differs in the seed alone: accepted
    assert model_card.seed_difference([model_card.read_run(r) for r in (runs[0], same)]) is None
    args = [str(runs[0]), str(runs[1]), str(other), "--name", "bad"]
    assert model_card.main(args) == 2
    err = capsys.readouterr().err
    assert "differ in more than the seed" in err and len(err.strip().splitlines()) == 1, err
