"""train.py's algorithms and configs: a tiny run of every algorithm, per-scenario sections, a
``--config`` file layered over the shipped one (README's example, run as written), ``--set``,
``--reward``, the saved resolved config, the default run directory, ``--help``, and each bad
input as one line with exit status 2 and nothing written."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest
import yaml

import train
from capture_bench.task.scenarios import ConfigError, list_scenarios, load_scenario
from capture_bench.training.config.hyperparameters import (
    ALGORITHMS,
    OFF_POLICY,
    load_hyperparameters,
    parse_override,
    resolve_hyperparameters,
)

#: A few hundred steps of each algorithm with a 16-unit network, set with --set only.
TINY = {
    "on": ["n_envs=2", "total_timesteps=128", "n_steps=32", "policy_kwargs.net_arch=[16]"],
    "off": [
        "n_envs=2", "total_timesteps=200", "learning_starts=64", "batch_size=32",
        "buffer_size=1000", "gradient_steps=1", "policy_kwargs.net_arch=[16]",
    ],
}  # fmt: skip
RUN_FILES = {
    "config.json",
    "hyperparameters.yaml",
    "wall_time.json",
    "model.zip",
    "policy.pt",
    "metadata.json",
}


def _tiny(algo: str) -> list[str]:
    extra = ["batch_size=32", "n_epochs=1"] if algo == "ppo" else []
    return [f"--set={item}" for item in TINY["off" if algo in OFF_POLICY else "on"] + extra]


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_a_tiny_run_of_each_algorithm_writes_a_complete_run_directory(tmp_path, algo):
    from capture_bench.agents.sb3_policy import load_sb3_policy
    from capture_bench.envs.capture_env import CaptureEnv

    run_dir = tmp_path / "run"
    argv = ["--algo", algo, *_tiny(algo), "--set", "checkpoint_freq=64", "--run-dir", str(run_dir)]
    assert train.main(argv) == 0
    assert RUN_FILES <= {p.name for p in run_dir.iterdir()}
    assert list((run_dir / "tb").rglob("events.out.tfevents.*"))
    assert list((run_dir / "checkpoints").glob("step_*"))
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["algorithm"] == algo.upper()
    assert meta["hyperparameters"]["policy_kwargs"]["net_arch"] == [16]
    assert "--set n_envs=2" in meta["command"] and f"--algo {algo}" in meta["command"]
    env = CaptureEnv("paper")
    try:  # the safe policy loads and acts
        agent = load_sb3_policy(run_dir, env)
        obs, _ = env.reset(seed=load_scenario("paper").validation_seeds[0])
        action, _ = agent.predict(obs, deterministic=True)
        assert env.action_space.contains(action)
    finally:
        env.close()


def test_the_saved_resolved_config_trains_the_same_hyperparameters(tmp_path):
    first = tmp_path / "first"
    argv = ["--algo", "ppo", *_tiny("ppo"), "--set", "gamma=0.97", "--reward", "sparse"]
    assert train.main([*argv, "--run-dir", str(first), "--set", "total_timesteps=64"]) == 0
    saved = json.loads((first / "config.json").read_text())
    hp = saved["hyperparameters"]
    assert hp["gamma"] == 0.97 and hp["reward"] == "sparse" and hp["n_steps"] == 32
    assert saved["origin"]["overrides"][-1] == "total_timesteps=64"
    resolved = first / "hyperparameters.yaml"
    assert "--set gamma=0.97" in resolved.read_text()  # the header says where it came from
    again, _, origin = resolve_hyperparameters("ppo", load_scenario("paper"), resolved)
    assert again == hp and origin["section"] is None
    second = tmp_path / "second"
    assert train.main(["--config", str(resolved), "--run-dir", str(second)]) == 0
    assert json.loads((second / "config.json").read_text())["hyperparameters"] == hp
    assert json.loads((second / "metadata.json").read_text())["reward"] == "sparse"


def test_metadata_names_the_code_the_run_started_from(tmp_path, monkeypatch):
    """A long run outlives commits made while it trains: metadata.json's git is the state
    recorded in config.json at the start, and git_at_save the state when it was saved."""
    import capture_bench.provenance as provenance

    states = iter([{"commit": "a" * 40, "dirty": False}, {"commit": "b" * 40, "dirty": True}])
    monkeypatch.setattr(provenance, "git_state", lambda *a: next(states))
    run_dir = tmp_path / "run"
    assert train.main(["--algo", "ppo", *_tiny("ppo"), "--run-dir", str(run_dir)]) == 0
    assert json.loads((run_dir / "config.json").read_text())["git"]["commit"] == "a" * 40
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["git"] == {"commit": "a" * 40, "dirty": False}
    assert meta["git_at_save"] == {"commit": "b" * 40, "dirty": True}


SECTIONS = """\
n_envs: 4
total_timesteps: 1000
gamma: 0.99
policy_kwargs: {net_arch: [32], log_std_init: -1.0}
tumbling:
  gamma: 0.95
  policy_kwargs: {net_arch: [64]}
CaptureBench/Drift-v1:
  n_envs: 8
"""


def test_a_scenario_section_overrides_the_top_level_keys_and_set_overrides_both(tmp_path):
    path = tmp_path / "ppo.yaml"
    path.write_text(SECTIONS)
    hp, _, origin = resolve_hyperparameters("ppo", load_scenario("tumbling"), path)
    assert hp["gamma"] == 0.95 and hp["n_envs"] == 4 and origin["section"] == "tumbling"
    shipped, _ = load_hyperparameters("ppo")  # the file is layered over ppo.yaml
    assert hp["policy_kwargs"] == {**shipped["policy_kwargs"], "net_arch": [64]}  # by entry
    hp, _, origin = resolve_hyperparameters("ppo", load_scenario("drift"), path)
    assert (
        hp["n_envs"] == 8 and hp["gamma"] == 0.99 and origin["section"] == "CaptureBench/Drift-v1"
    )
    hp, _, origin = resolve_hyperparameters(
        "ppo", load_scenario("paper"), path, ["gamma=0.9", "policy_kwargs.net_arch=[8, 8]"]
    )
    assert hp["gamma"] == 0.9 and hp["policy_kwargs"]["net_arch"] == [8, 8]
    assert origin["section"] is None and hp["n_envs"] == 4
    # train.py reads the section of the scenario it trains on
    run_dir = tmp_path / "run"
    argv = ["--config", str(path), "--scenario", "tumbling", "--set", "total_timesteps=64"]
    tiny = ["--set=n_steps=32", "--set=batch_size=32", "--set=n_epochs=1", "--n-envs", "2"]
    assert train.main([*argv, *tiny, "--run-dir", str(run_dir)]) == 0
    hp = json.loads((run_dir / "config.json").read_text())["hyperparameters"]
    assert hp["gamma"] == 0.95 and hp["n_envs"] == 2  # --n-envs wins over the file


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            SECTIONS + "tumbling_x:\n  gamma: 0.9\n",
            ("unknown key 'tumbling_x'", "scenario section"),
        ),
        (SECTIONS + "tumbling_x: 3\n", ("unknown key 'tumbling_x'",)),
        (SECTIONS + "paper: 3\n", ("unknown key 'paper'", "holding a mapping")),
        (SECTIONS + "paper:\n  gama: 0.9\n", ("unknown key 'paper.gama'", "valid keys")),
        (SECTIONS + "paper:\n  gamma: 2\n", ("key 'paper.gamma'", "[0, 1]")),
        (SECTIONS + "CaptureBench/Tumbling-v1:\n  gamma: 0.9\n", ("two sections",)),
    ],
)
def test_a_bad_scenario_section_names_the_file_and_key(tmp_path, text, expected):
    path = tmp_path / "ppo.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as raised:
        resolve_hyperparameters("ppo", load_scenario("tumbling"), path)
    assert str(path) in str(raised.value)
    for part in expected:
        assert part in str(raised.value)


def test_overrides_parse_as_yaml_and_are_checked_like_the_file():
    assert parse_override("learning_rate=1e-3", "sac") == {"learning_rate": 1e-3}
    assert parse_override("learning_rate=lin_3e-4", "ppo") == {"learning_rate": "lin_3e-4"}
    assert parse_override("policy_kwargs.net_arch={pi: [8], qf: [8]}", "tqc") == {
        "policy_kwargs": {"net_arch": {"pi": [8], "qf": [8]}}
    }
    assert parse_override(" gamma = 0.5 ", "a2c") == {"gamma": 0.5}


def one_line_error(capsys, argv: list[str], *expected: str) -> str:
    assert train.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("train.py: error: ") and "Traceback" not in err
    for text in expected:
        assert text in err, err
    return err


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--algo", "dqn"], ("'dqn'", ", ".join(ALGORITHMS))),
        (["--set", "gamma"], ("--set 'gamma'", "KEY=VALUE")),
        (["--set", "=1"], ("KEY=VALUE",)),
        (["--set", "gamma="], ("no value",)),
        (["--set", "gama=0.9"], ("--set gama=0.9", "unknown key 'gama'", "valid keys", "gamma")),
        (["--set", "gamma=1.5"], ("--set gamma=1.5", "key 'gamma'", "1.5", "[0, 1]")),
        (["--set", "gamma=[1"], ("--set gamma=[1", "not valid YAML")),
        (["--set", "n_critics=2"], ("unknown key 'n_critics'",)),  # PPO has no critics
        (["--set", "policy_kwargs.n_critics=2"], ("unknown key 'policy_kwargs.n_critics'",)),
        (["--set", "gamma.x=1"], ("only policy_kwargs.<name> may be dotted",)),
        (
            ["--algo", "td3", "--set", "policy_kwargs.ortho_init=true"],
            ("policy_kwargs.ortho_init",),
        ),
        (["--algo", "sac", "--set", "policy_kwargs.net_arch={vf: [8]}"], ("pi: [...], qf: [...]",)),
        (["--reward", "potential"], ("--reward", "dense", "sparse", "shaped")),
        (["--n-envs", "0"], ("--n-envs must be >= 1",)),
        (["--reward", "shaped", "--set", "gamma=0.9"], ("shaped", "gamma 0.99", "gamma is 0.9")),
        (["--n-envs", "100000000"], ("--n-envs 100000000", "at most", "batched")),
    ],
)
def test_each_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, argv, expected):
    run_dir = tmp_path / "run"
    one_line_error(capsys, [*argv, "--run-dir", str(run_dir)], *expected)
    assert not run_dir.exists()


def test_set_is_refused_with_resume_and_nothing_changes(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert train.main(["--algo", "a2c", *_tiny("a2c"), "--run-dir", str(run_dir)]) == 0
    before = (run_dir / "config.json").read_bytes()
    one_line_error(capsys, ["--resume", str(run_dir), "--set", "gamma=0.5"], "--set")
    assert (run_dir / "config.json").read_bytes() == before


def test_an_existing_run_is_never_overwritten(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert train.main(["--algo", "a2c", *_tiny("a2c"), "--run-dir", str(run_dir)]) == 0
    before = {p: p.read_bytes() for p in run_dir.rglob("*") if p.is_file()}
    one_line_error(capsys, ["--algo", "ppo", "--run-dir", str(run_dir)], "already holds a run")
    assert {p: p.read_bytes() for p in run_dir.rglob("*") if p.is_file()} == before


def test_help_lists_algorithms_scenarios_and_examples(capsys):
    assert train.main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "examples:" in out and "--set" in out and "--reward" in out
    assert ", ".join(ALGORITHMS) in out
    for name in list_scenarios():
        assert name in out


def test_shipped_configs_resolve_for_every_scenario():
    for algo in ALGORITHMS:
        for name in list_scenarios():
            hp, path, _ = resolve_hyperparameters(algo, load_scenario(name))
            assert path.name == f"{algo}.yaml" and hp["n_envs"] >= 1
            yaml.safe_dump(hp)  # plain data: what hyperparameters.yaml holds
    assert Path(path).is_file()


# --------------------------------------------------------------------------- README's --config example

README = Path(__file__).parents[1] / "README.md"


def _readme_config_example() -> tuple[str, list[str]]:
    """README's training section: its example hyper-parameter file (the yaml block) and the
    options of its ``--config my_ppo.yaml`` command."""
    training = README.read_text().split("\n## Training\n", 1)[1].split("\n## ", 1)[0]
    text = re.search(r"```yaml\n(.*?)```", training, re.S).group(1)
    line = next(ln for ln in training.splitlines() if "--config my_ppo.yaml" in ln)
    words = shlex.split(line.split("#", 1)[0])
    assert words[:2] == ["python", "train.py"], line
    return text, words[2:]


def test_readmes_config_example_runs_as_written_over_the_shipped_defaults(tmp_path, capsys):
    text, options = _readme_config_example()
    path = tmp_path / "my_ppo.yaml"
    path.write_text(text)  # saved as written
    argv = [str(path) if word == "my_ppo.yaml" else word for word in options]
    # 32 envs as subprocesses are not a fast test; the batched env draws the same episodes
    # (tests/test_sb3_vec_env.py)
    argv = [word if word != "subproc" else "batched" for word in argv]
    run_dir = tmp_path / "run"
    assert train.main([*argv, "--total-timesteps", "3000", "--run-dir", str(run_dir)]) == 0
    shipped, _, _ = resolve_hyperparameters("ppo", load_scenario("paper"))
    written = yaml.safe_load(text)
    top = {k: v for k, v in written.items() if k != "tumbling"}
    expected = {**shipped, **top, "reward": "sparse", "total_timesteps": 3000}
    saved = json.loads((run_dir / "config.json").read_text())
    assert saved["hyperparameters"] == expected  # the shipped n_steps 64, not SB3's 2048
    assert saved["origin"]["defaults"]["file"].endswith("ppo.yaml")
    rollout = expected["n_steps"] * expected["n_envs"]  # 64 x 32 = 2048
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["total_timesteps"] == -(-3000 // rollout) * rollout == 4096
    assert "rounded up to 4096" in capsys.readouterr().out
    # the file's tumbling section applies on tumbling, over the shipped keys
    hp, _, origin = resolve_hyperparameters("ppo", load_scenario("tumbling"), path)
    assert origin["section"] == "tumbling" and hp["gamma"] == 0.95 and hp["n_steps"] == 64
    assert hp["policy_kwargs"] == {**shipped["policy_kwargs"], "net_arch": [256, 256]}


def test_a_complete_config_file_gets_nothing_from_the_shipped_one(tmp_path):
    """A file setting every key the shipped one sets (hyperparameters.yaml, best.yaml) is the
    run's hyper-parameters as written, with or without the layering."""
    shipped, path = load_hyperparameters("sac")
    own = {**shipped, "gamma": 0.9, "policy_kwargs": {**shipped["policy_kwargs"], "n_critics": 3}}
    (tmp_path / "sac.yaml").write_text(yaml.safe_dump(own))
    hp, _, origin = resolve_hyperparameters("sac", load_scenario("tumbling"), tmp_path / "sac.yaml")
    assert hp == own and origin["defaults"] == {"file": str(path), "section": None}


# --------------------------------------------------------------------------- the run directory


def test_without_run_dir_each_run_gets_a_directory_of_its_own(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    tiny = ["--algo", "a2c", *_tiny("a2c")]
    assert train.main(tiny) == 0
    first = tmp_path / "runs" / "paper-a2c-0"
    before = {p: p.read_bytes() for p in first.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert train.main([*tiny, "--set", "gamma=0.9"]) == 0  # the same default name: taken
    out = capsys.readouterr().out
    second = tmp_path / "runs" / "paper-a2c-0_2"
    assert "runs/paper-a2c-0 is taken" in out and "goes to runs/paper-a2c-0_2" in out
    assert json.loads((second / "config.json").read_text())["hyperparameters"]["gamma"] == 0.9
    assert {p: p.read_bytes() for p in first.rglob("*") if p.is_file()} == before


def test_the_free_run_directory_skips_anything_that_holds_files(tmp_path):
    from capture_bench.training.common.run import free_run_dir

    base = tmp_path / "paper-ppo-0"
    assert free_run_dir(base) == base
    base.mkdir()
    assert free_run_dir(base) == base  # an empty folder holds nothing to mix with
    (base / "notes.txt").write_text("mine")
    (tmp_path / "paper-ppo-0_2").write_text("a file")
    (tmp_path / "paper-ppo-0_3").mkdir()
    assert free_run_dir(base) == tmp_path / "paper-ppo-0_3"


def test_a_shipped_key_that_clashes_with_the_file_names_where_it_came_from(tmp_path, capsys):
    (tmp_path / "mine.yaml").write_text("normalize: true\n")
    argv = ["--config", str(tmp_path / "mine.yaml"), "--run-dir", str(tmp_path / "run")]
    one_line_error(capsys, argv, "mine.yaml", "ppo.yaml, under this file", "extractor: flatten")
    assert not (tmp_path / "run").exists()
    (tmp_path / "mine.yaml").write_text(
        "normalize: true\npolicy_kwargs: {features_extractor: flatten}\n"
    )
    hp, _, _ = resolve_hyperparameters("ppo", load_scenario("paper"), tmp_path / "mine.yaml")
    shipped, _ = load_hyperparameters("ppo")
    assert (
        hp["normalize"] and hp["policy_kwargs"]["net_arch"] == shipped["policy_kwargs"]["net_arch"]
    )
