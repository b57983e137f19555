"""Model cards: every shipped model has its card's fields and reproduces, on a few episodes, the
validation results its card records (bit for bit on the reference's kind of machine, within
``replay_agrees``'s statistics on any other CPU); shipping a run writes the card."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import train
from capture_bench.provenance import reproduction_key
from capture_bench.task.scenarios import load_scenario
from capture_bench.training.train.model_card import (
    CARD_BATCH,
    CARD_FIELDS,
    REPLAY_CHECK,
    replay_agrees,
    ship,
    validate_policy,
)

ROOT = Path(__file__).parents[1]
MODELS = ROOT / "models"
CARDED = sorted(p for p in MODELS.glob("*") if (p / "metadata.json").is_file()
                and "model_card" in json.loads((p / "metadata.json").read_text()))  # fmt: skip
#: The kind of machine on which every card's episodes replay bit for bit: the one that made the
#: test suite's stored reference (its CPU, BLAS and numerical packages).
_MADE = json.loads((ROOT / "tests" / "data" / "default_suite_reference.json").read_text())
EXACT_HERE = reproduction_key() == reproduction_key(_MADE["machine"], _MADE["packages"])
#: Episodes per model replayed on another CPU, where a statistical check needs more than one batch.
STATISTICAL_EPISODES = 16


def _check_replay(model_dir: Path, card: dict, count: int, exact: bool = EXACT_HERE) -> None:
    """The card's first ``count`` episodes of each scenario replayed: bit for bit where
    ``exact``, else within `replay_agrees`'s statistics, over at least
    `STATISTICAL_EPISODES` episodes in all."""
    if not exact:
        per_scenario = -(-STATISTICAL_EPISODES // len(card["validation"]))
        count = max(count, -(-per_scenario // CARD_BATCH) * CARD_BATCH)  # whole batches
    recorded, replayed = [], []
    for scenario, card_scenario in card["validation"].items():
        episodes = card_scenario["episodes"][:count]
        replay = validate_policy(model_dir, scenario, [e["seed"] for e in episodes])
        recorded += episodes
        replayed += replay["episodes"]
        if exact:
            for want, got in zip(episodes, replay["episodes"], strict=True):
                assert got["captured"] == want["captured"], (model_dir.name, scenario, want)
                if want["captured"]:
                    assert got["capture_time"] == pytest.approx(want["capture_time"], rel=1e-6)
    assert replay_agrees(recorded, replayed) == [], model_dir.name


@pytest.mark.parametrize("model_dir", CARDED, ids=lambda p: p.name)
def test_every_shipped_model_card_has_its_fields_and_reproduces_its_validation(model_dir):
    card = json.loads((model_dir / "metadata.json").read_text())["model_card"]
    assert set(CARD_FIELDS) <= set(card)
    assert card["command"].startswith("python train.py") and card["total_timesteps"] > 0
    assert card["hardware"]["cores"] >= 1 and card["wall_time_s"] > 0
    assert REPLAY_CHECK in (model_dir / "README.md").read_text()  # says how it is replayed
    _check_replay(model_dir, card, count=CARD_BATCH)  # the card's first batch, as it was played


def _episodes(outcomes: str, times: list[float] | None = None) -> list[dict]:
    times = times or [1.0] * len(outcomes)
    return [
        {"seed": i, "captured": o == "c", "capture_time": t if o == "c" else None}
        for i, (o, t) in enumerate(zip(outcomes, times))
    ]


def test_a_replay_on_another_cpu_may_move_knife_edge_episodes_but_not_the_policy():
    """Another CPU's rounding flips a few knife-edge episodes both ways and moves capture times
    by a little: that agrees; losing most captures, or times moved by a tenth, does not."""
    card = _episodes("cccccccccccccccf")  # 15 of 16
    assert replay_agrees(card, card) == []
    assert replay_agrees(card, _episodes("cccfcccccccccccc")) == []  # two flipped, count equal
    assert replay_agrees(card, _episodes("ccccccccccccffff")) == []  # 12 of 16: within 99%
    assert "captured 6 of 16" in replay_agrees(card, _episodes("ccccccffffffffff"))[0]
    moved = _episodes("cccccccccccccccf", [1.1] * 16)
    assert "moved by a median 10.0%" in replay_agrees(card, moved)[0]
    assert replay_agrees(card, _episodes("cccccccccccccccf", [1.01] * 16)) == []
    assert "other seeds" in replay_agrees(card, card[1:] + card[:1])[0]


@pytest.mark.parametrize("model_dir", CARDED[:1], ids=lambda p: p.name)
def test_the_other_cpu_check_passes_on_this_machine_too(model_dir):
    """The statistical check that other CPUs run, run here on the same card (here it replays
    bit for bit, so it must agree)."""
    card = json.loads((model_dir / "metadata.json").read_text())["model_card"]
    _check_replay(model_dir, card, count=CARD_BATCH, exact=False)


SEEDED = [
    p for p in CARDED if "seeds" in json.loads((p / "metadata.json").read_text())["model_card"]
]


@pytest.mark.parametrize("model_dir", SEEDED, ids=lambda p: p.name)
def test_a_card_of_several_seeds_names_three_the_shipped_one_and_its_policy(model_dir):
    """A row trained with several seeds: three of them, each one's policy under seeds/, the
    shipped one the model's own policy and named in the README, chosen on validation seeds."""
    card = json.loads((model_dir / "metadata.json").read_text())["model_card"]
    seeds = card["seeds"]
    assert len(seeds["trained"]) == 3 and seeds["shipped"] in seeds["trained"]
    for seed in seeds["trained"]:
        assert (model_dir / "seeds" / str(seed) / "policy.pt").is_file()
    shipped = model_dir / "seeds" / str(seeds["shipped"]) / "policy.pt"
    assert shipped.read_bytes() == (model_dir / "policy.pt").read_bytes()
    readme = (model_dir / "README.md").read_text()
    assert f"| {seeds['shipped']} (shipped) |" in readme
    assert "validation" in seeds["selection"]
    for scenario, validation in card["validation"].items():
        published = set(load_scenario(scenario).evaluation_seeds)
        assert published.isdisjoint(e["seed"] for e in validation["episodes"])


def test_every_shipped_model_has_a_card():
    shipped = [p for p in MODELS.glob("*") if (p / "metadata.json").is_file()]
    assert shipped and set(shipped) == set(CARDED), "a model under models/ has no model card"


def test_shipping_a_run_writes_the_model_and_its_card(tmp_path):
    run_dir = tmp_path / "run"
    sets = ["n_envs=2", "n_steps=32", "batch_size=32", "n_epochs=1", "total_timesteps=64",
            "policy_kwargs.net_arch=[8]"]  # fmt: skip
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) == 0
    target = ship(run_dir, "tiny", episodes=3, out=tmp_path / "models")
    card = json.loads((target / "metadata.json").read_text())["model_card"]
    assert card["scenarios"] == ["paper"] and len(card["validation"]["paper"]["episodes"]) == 3
    assert "## Validation" in (target / "README.md").read_text()
    _check_replay(target, card, count=3)
    with pytest.raises(Exception, match="already exists"):
        ship(run_dir, "tiny", episodes=3, out=tmp_path / "models")


def test_shipping_a_runs_best_validation_says_so(tmp_path):
    run_dir = tmp_path / "run"
    sets = ["n_envs=2", "n_steps=32", "batch_size=32", "n_epochs=1", "total_timesteps=128",
            "policy_kwargs.net_arch=[8]", "eval_freq=64", "eval_episodes=2"]  # fmt: skip
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) == 0
    step = json.loads((run_dir / "best" / "validation.json").read_text())["step"]
    target = ship(run_dir / "best", "tiny-best", episodes=2, out=tmp_path / "models")
    card = json.loads((target / "metadata.json").read_text())["model_card"]
    assert card["policy"] == {"kind": "best validation", "step": step, "seeds": 2}
    assert card["command"].startswith("python train.py") and card["scenarios"] == ["paper"]
    assert f"at step {step:,}" in (target / "README.md").read_text()
    assert (target / "model.zip").is_file()  # best/ keeps SB3's file too
    _check_replay(target, card, count=2)
    final = ship(run_dir, "tiny", episodes=2, out=tmp_path / "models")
    assert json.loads((final / "metadata.json").read_text())["model_card"]["policy"] == {
        "kind": "final"
    }


def test_shipping_a_directory_without_a_run_config_is_one_line(tmp_path, capsys):
    from capture_bench.training.train.model_card import main

    lone = tmp_path / "best"
    lone.mkdir()
    (lone / "policy.pt").write_bytes(b"")
    (lone / "metadata.json").write_text("{}")
    (lone / "validation.json").write_text('{"step": 64, "seeds": [1]}')
    assert main([str(lone), "--name", "x"]) == 2
    err = capsys.readouterr().err
    assert "config.json: missing" in err and len(err.strip().splitlines()) == 1, err


def test_revalidating_a_card_keeps_what_it_shipped_with_and_writes_one_section(tmp_path):
    from capture_bench.training.train.model_card import (
        ENVELOPE_SECTION,
        VALIDATION_HEADING,
        VALIDATION_V0_HEADING,
        revalidate,
    )

    run_dir = tmp_path / "run"
    sets = ["n_envs=2", "n_steps=32", "batch_size=32", "n_epochs=1", "total_timesteps=64",
            "policy_kwargs.net_arch=[8]"]  # fmt: skip
    assert train.main([*(f"--set={s}" for s in sets), "--run-dir", str(run_dir)]) == 0
    target = ship(run_dir, "tiny", episodes=2, out=tmp_path / "models")
    shipped = json.loads((target / "metadata.json").read_text())["model_card"]["validation"]
    for _ in range(2):  # a second run rewrites the section, keeps the first results as v0
        after = revalidate(target)
    card = json.loads((target / "metadata.json").read_text())["model_card"]
    same = lambda a, b: json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)  # noqa: E731
    assert same(card["validation_v0"], shipped) and same(card["validation"], after)
    readme = (target / "README.md").read_text()
    assert readme.count(ENVELOPE_SECTION) == 1
    # the table as shipped stays, named for the rule it was made under, and points at v0's field
    assert VALIDATION_V0_HEADING in readme and VALIDATION_HEADING not in readme
    assert "(`model_card.validation_v0`)" in readme and "(`model_card.validation`)" not in readme
    _check_replay(target, card, count=2)
