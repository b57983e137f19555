"""Model cards (issue 14 point 3): every shipped model has its card's fields and reproduces, on
a few episodes, the validation results its card records; shipping a run writes the card."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import train
from capture_bench.training.model_card import CARD_BATCH, CARD_FIELDS, ship, validate_policy

MODELS = Path(__file__).parents[1] / "models"
CARDED = sorted(p for p in MODELS.glob("*") if (p / "metadata.json").is_file()
                and "model_card" in json.loads((p / "metadata.json").read_text()))  # fmt: skip


def _check_replay(model_dir: Path, card: dict, count: int) -> None:
    for scenario, recorded in card["validation"].items():
        episodes = recorded["episodes"][:count]
        replay = validate_policy(model_dir, scenario, [e["seed"] for e in episodes])
        for want, got in zip(episodes, replay["episodes"], strict=True):
            assert got["captured"] == want["captured"], (model_dir.name, scenario, want)
            if want["captured"]:
                assert got["capture_time"] == pytest.approx(want["capture_time"], rel=1e-6)


@pytest.mark.parametrize("model_dir", CARDED, ids=lambda p: p.name)
def test_every_shipped_model_card_has_its_fields_and_reproduces_its_validation(model_dir):
    card = json.loads((model_dir / "metadata.json").read_text())["model_card"]
    assert set(CARD_FIELDS) <= set(card)
    assert card["command"].startswith("python train.py") and card["total_timesteps"] > 0
    assert card["hardware"]["cores"] >= 1 and card["wall_time_s"] > 0
    assert (model_dir / "README.md").is_file()
    _check_replay(model_dir, card, count=CARD_BATCH)  # the card's first batch, as it was played


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
    from capture_bench.training.model_card import main

    lone = tmp_path / "best"
    lone.mkdir()
    (lone / "policy.pt").write_bytes(b"")
    (lone / "metadata.json").write_text("{}")
    (lone / "validation.json").write_text('{"step": 64, "seeds": [1]}')
    assert main([str(lone), "--name", "x"]) == 2
    err = capsys.readouterr().err
    assert "config.json: missing" in err and len(err.strip().splitlines()) == 1, err
