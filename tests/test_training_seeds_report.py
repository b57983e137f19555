"""A learned agent shipped from several training seeds: the evaluation plays every seed's policy
on the row's scenarios and episode seeds; the row, its rank and its paired comparisons stay the
shipped policy's, and the report carries the seeds' IQM with its interval (on the ranking row
and in the section "Training seeds") and each seed's score. A report without such an agent has
neither."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from capture_bench.evaluation.reporting import training_seeds
from capture_bench.evaluation.reporting.report import NOTES, markdown, scenario_notes
from capture_bench.evaluation.reporting.summary import score
from capture_bench.rliable_stats import aggregate_estimates

MODELS = Path(__file__).parents[1] / "models"
#: Three "training seeds" of one model: shipped policies standing in for them (the evaluation
#: reads the card and the folders only), seed 1 the one shipped; seed 2 a seed's own folder of
#: ``dagger-dls-all`` (a policy that captures, with no card of several seeds).
SEED_POLICIES = {0: "dagger-dls-paper/seeds/0", 1: "dagger-dls-paper", 2: "dagger-dls-all/seeds/0"}
SHIPPED = 1


def _seeded_model(root: Path) -> Path:
    """``root/seeded``: ``dagger-dls-paper`` shipped as seed 1 of three, the others in ``seeds/``."""
    model = root / "seeded"
    for seed, name in SEED_POLICIES.items():
        folder = model / "seeds" / str(seed)
        folder.mkdir(parents=True)
        for file in ("policy.pt", "metadata.json"):
            shutil.copy2(MODELS / name / file, folder / file)
    shutil.copy2(MODELS / SEED_POLICIES[SHIPPED] / "policy.pt", model / "policy.pt")
    meta = json.loads((MODELS / SEED_POLICIES[SHIPPED] / "metadata.json").read_text())
    meta["model_card"]["seeds"] = {
        "trained": sorted(SEED_POLICIES),
        "shipped": SHIPPED,
        "selection": "median validation score (validation seeds)",
    }
    (model / "metadata.json").write_text(json.dumps(meta))
    return model


@pytest.fixture(scope="module")
def report(tmp_path_factory, evaluated):
    """incremental_ik, the seeded model and its seed 2's policy as an agent of its own, on two
    scenarios x 4 seeds, serial."""
    root = tmp_path_factory.mktemp("seeded")
    model = _seeded_model(root)
    agents = f"incremental_ik,{model},{model / 'seeds' / '2'}"
    argv = ["--agents", agents, "--scenarios", "paper,grasp", "--episodes", "4", "--workers", "1"]
    return evaluated(argv, root / "out")


def _scenario_means(records, agent: str, scenarios: list[str]) -> list[float]:
    return [
        float(np.mean([score(r) for r in records if r.agent == agent and r.scenario == name]))
        for name in scenarios
    ]


def test_every_seed_plays_the_rows_episodes_and_its_iqm_is_rliables(report):
    data, _ = report
    seeds = data.training_seeds["seeded"]
    assert seeds.seeds == [0, 1, 2] and seeds.shipped == SHIPPED
    assert seeds.scenarios == ["paper", "grasp"] and seeds.scores.shape == (3, 2)
    # the shipped seed's row is the agent's own episodes; seed 2's, its policy played alone
    assert seeds.scores[1].tolist() == _scenario_means(data.records, "seeded", seeds.scenarios)
    assert seeds.scores[2].tolist() == _scenario_means(data.records, "2", seeds.scenarios)
    assert seeds.scores[2].min() > 0  # a policy that captures: the check compares scores
    want = aggregate_estimates({"m": seeds.scores})["m"]["iqm"]
    assert seeds.iqm == want and want.low <= want.value <= want.high
    # nothing else of the seeds enters the leaderboard: its records are its agents' alone
    assert {r.agent for r in data.records} == {"incremental_ik", "seeded", "2"}
    assert set(data.training_seeds) == {"seeded"}  # seed 2's policy alone is an unseeded model


def test_results_json_and_the_markdown_carry_the_seed_interval_and_each_seeds_score(report):
    data, folder = report
    results = json.loads((folder / "results.json").read_text())
    row = next(r for r in results["ranking"] if r["agent"] == "seeded")
    iqm = data.training_seeds["seeded"].iqm
    assert row[training_seeds.RANKING_KEY] == pytest.approx(iqm.as_dict())
    others = [r for r in results["ranking"] if r["agent"] != "seeded"]
    assert all(training_seeds.RANKING_KEY not in r for r in others)
    section = results[training_seeds.KEY]["agents"]["seeded"]
    assert section["seeds"] == [0, 1, 2] and section["shipped"] == SHIPPED
    assert list(section["per_seed"]) == ["0", "1", "2"] and len(section["scores"]) == 3
    hashes = results["provenance"]["config_hashes"]["models"]["seeded"]["training_seeds"]
    assert sorted(hashes) == ["0", "2"] and all("policy.pt" in h for h in hashes.values())
    text = (folder / "leaderboard.md").read_text()
    ranking = text[text.index("## Overall ranking") :].split("\n\n")[1].splitlines()
    assert ranking[0].endswith(f"| {training_seeds.COLUMN} |")
    seeded_row = next(line for line in ranking if line.startswith("| ") and "| seeded |" in line)
    assert seeded_row.endswith(f"| {training_seeds.fmt(iqm)} |")
    assert f"## {training_seeds.TITLE}" in text
    per_seed = ", ".join(
        f"{s}: {v:.3f}" for s, v in zip([0, 1, 2], data.training_seeds["seeded"].per_seed())
    )
    assert f"| seeded | 0, 1, 2 | {SHIPPED} | {per_seed} |" in text
    assert "learned rows: the shipped policy (median of its training seeds)" in text.lower()
    html = (folder / "leaderboard.html").read_text()
    assert training_seeds.COLUMN in html and training_seeds.fmt(iqm) in html


def test_a_report_without_training_seeds_has_neither_column_nor_section(report):
    data, _ = report
    plain = replace(data, training_seeds={})
    text = markdown(plain)
    assert training_seeds.COLUMN not in text and f"## {training_seeds.TITLE}" not in text
    assert scenario_notes(plain) == NOTES and training_seeds.ROW_POLICY not in text


def test_a_card_naming_a_seed_without_its_policy_is_refused_before_any_episode(tmp_path, capsys):
    from capture_bench.evaluation.cli import main

    model = _seeded_model(tmp_path)
    shutil.rmtree(model / "seeds" / "2")
    argv = ["--agents", str(model), "--scenarios", "paper", "--episodes", "1", "--workers", "1"]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "training seeds [0, 1, 2]" in err and "holds no policy" in err, err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
