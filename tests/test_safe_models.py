"""Trained models load without unpickling anything; an SB3 .zip only with --trust-model."""

from __future__ import annotations

import base64
import json
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
from stand_in import sb3_model as _sb3_model

import evaluate
import train
from capture_bench.agents.convert import main as convert_main
from capture_bench.agents.policy_file import (
    FORMAT,
    ObservationNormalizer,
    PolicyLoadError,
    save_policy,
)
from capture_bench.agents.sb3_policy import (
    SB3Policy,
    load_policy,
    load_sb3_policy,
    load_trusted,
    read_metadata,
)
from capture_bench.evaluation.running.agents_loading import shipped_models

MODELS = Path(__file__).parents[1] / "models"


class _Payload:
    """Unpickling this creates ``marker``: the shape of a hostile model file."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def _observations(n: int = 100, shape: tuple[int, ...] = (16,)) -> np.ndarray:
    rng = np.random.default_rng(7)
    return rng.uniform(-3, 3, (n, *shape)).astype(np.float32)


def _assert_same_actions(a: SB3Policy, b: SB3Policy) -> None:
    space = a.policy.observation_space
    if hasattr(space, "spaces"):  # a pixel policy's Dict: sampled images and states
        space.seed(7)
        observations = [space.sample() for _ in range(10)]
    else:  # the estimate's 16 numbers, or a front end's vector (models/pose-dagger-dls-paper)
        observations = list(_observations(shape=space.shape))
    for obs in observations:
        np.testing.assert_array_equal(a.predict(obs)[0], b.predict(obs)[0])


# --------------------------------------------------------------------------- hostile files


def _zip_only_model(directory: Path, payload_marker: Path | None = None) -> Path:
    """An SB3 .zip model directory (as SB3 saves it), optionally carrying a pickled payload."""
    model, _ = _sb3_model("PPO")
    directory.mkdir(parents=True)
    model.save(directory / "model.zip")
    if payload_marker is not None:
        with zipfile.ZipFile(directory / "model.zip") as archive:
            entries = {name: archive.read(name) for name in archive.namelist()}
        data = json.loads(entries["data"])
        hostile = pickle.dumps(_Payload(payload_marker))
        data["payload"] = {
            ":type:": "<class 'object'>",
            ":serialized:": base64.b64encode(hostile).decode(),
        }
        entries["data"] = json.dumps(data).encode()
        with zipfile.ZipFile(directory / "model.zip", "w") as archive:
            for name, content in entries.items():
                archive.writestr(name, content)
    (directory / "metadata.json").write_text(json.dumps({"algorithm": "PPO", "model": "model.zip"}))
    return directory


def test_a_pickled_payload_in_a_zip_never_runs_by_default(tmp_path, capsys):
    marker = tmp_path / "payload-ran"
    model = _zip_only_model(tmp_path / "hostile", payload_marker=marker)
    argv = ["--agents", str(model), "--suite", "quick", "--workers", "1"]
    assert evaluate.main([*argv, "--out", str(tmp_path / "reports")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "--trust-model" in err and "pickled" in err
    assert not marker.exists()
    assert not (tmp_path / "reports").exists()


def test_the_same_zip_loads_with_trust_model_and_then_its_pickles_do_run(tmp_path, capsys):
    marker = tmp_path / "payload-ran"
    model = _zip_only_model(tmp_path / "hostile", payload_marker=marker)
    argv = ["--agents", str(model), "--suite", "quick", "--scenarios", "paper", "--episodes", "1"]
    argv += ["--workers", "1", "--trust-model", "--out", str(tmp_path / "reports")]
    assert evaluate.main(argv) == 0
    assert marker.exists()  # what --trust-model means: the file's code ran
    payload = json.loads(next((tmp_path / "reports").rglob("results.json")).read_text())
    provenance = payload["provenance"]["config_hashes"]["models"]["hostile"]
    assert provenance["loaded_from"] == "SB3 .zip (trusted)"


def test_python_equivalent_of_trust_model(tmp_path):
    from capture_bench.envs.capture_env import CaptureEnv

    model = _zip_only_model(tmp_path / "plain")
    env = CaptureEnv("paper")
    try:
        with pytest.raises(PolicyLoadError, match="trust_model=True"):
            load_sb3_policy(model, env)
        agent = load_sb3_policy(model, env, trust_model=True)
        obs, _ = env.reset(seed=0)
        assert env.action_space.contains(agent.predict(obs)[0])
    finally:
        env.close()


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
def test_a_weights_file_that_would_run_code_is_refused(tmp_path):
    model, _ = _sb3_model("PPO")
    directory = tmp_path / "m"
    save_policy(directory, "PPO", model.policy)
    marker = tmp_path / "payload-ran"
    (directory / "policy.pt").write_bytes(pickle.dumps({"x": _Payload(marker)}))
    metadata = read_metadata(directory)
    with pytest.raises(PolicyLoadError, match="weights_only"):
        load_policy(metadata, trust_model=True)  # trust never applies to the safe form
    assert not marker.exists()


# --------------------------------------------------------------------------- same actions


@pytest.mark.parametrize("model_dir", shipped_models(MODELS), ids=lambda p: Path(p).name)
def test_every_shipped_model_loads_safely_with_the_actions_of_sb3_loading(model_dir):
    metadata = read_metadata(model_dir)
    assert metadata.weights_file is not None and metadata.declaration is not None
    assert (Path(model_dir) / "README.md").is_file()  # its model card
    safe = load_policy(metadata)  # no trust needed
    trusted = load_trusted(metadata)  # SB3's own loading of the original .zip
    _assert_same_actions(
        SB3Policy(safe.policy, "safe", safe.normalizer),
        SB3Policy(trusted.policy, "sb3", trusted.normalizer),
    )


@pytest.mark.parametrize(
    ("algorithm", "normalize"),
    [("PPO", True), ("A2C", False), ("SAC", True), ("TD3", False), ("DDPG", False)],
)
def test_a_trained_model_round_trips_through_the_safe_form(algorithm, normalize, tmp_path):
    model, venv = _sb3_model(algorithm, normalize=normalize, learn=64)
    normalizer = ObservationNormalizer.from_vecnormalize(venv) if venv is not None else None
    save_policy(tmp_path / "m", algorithm, model.policy, normalizer, extra={"scenario": "paper"})
    loaded = load_policy(read_metadata(tmp_path / "m"))
    agent = SB3Policy(loaded.policy, "safe", loaded.normalizer)
    for obs in _observations():
        seen = venv.normalize_obs(obs) if venv is not None else obs
        expected, _ = model.predict(seen, deterministic=True)
        np.testing.assert_array_equal(agent.predict(obs)[0], expected)


def test_train_py_writes_a_run_directory_that_loads_safely(tmp_path):
    config = tmp_path / "tiny.yaml"
    config.write_text(
        "n_envs: 1\ntotal_timesteps: 32\npolicy_kwargs: {net_arch: [8], features_extractor: flatten}\n"
        "n_steps: 32\nbatch_size: 32\nn_epochs: 1\nnormalize: true\n"
    )
    run_dir = tmp_path / "run"
    argv = ["--algo", "ppo", "--scenario", "paper", "--config", str(config)]
    assert train.main([*argv, "--run-dir", str(run_dir)]) == 0
    metadata = read_metadata(run_dir)
    assert metadata.weights_file == run_dir / "policy.pt"
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["format"] == FORMAT and meta["normalization"] is not None
    assert meta["hyperparameters"]["normalize"] is True  # provenance kept beside the declaration
    safe = load_policy(metadata)
    trusted = load_trusted(metadata)
    _assert_same_actions(
        SB3Policy(safe.policy, "safe", safe.normalizer),
        SB3Policy(trusted.policy, "sb3", trusted.normalizer),
    )


# --------------------------------------------------------------------------- bad declarations


def _declared(tmp_path: Path, algorithm: str = "PPO") -> Path:
    model, _ = _sb3_model(algorithm)
    save_policy(tmp_path / "m", algorithm, model.policy)
    return tmp_path / "m"


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"format": "pickle"}, "key 'format'"),
        ({"algorithm": "DQN"}, "key 'algorithm'"),
        ({"weights": "../elsewhere.pt"}, "key 'weights'"),
        ({"policy_kwargs": {"net_arch": [16, -1]}}, "policy_kwargs.net_arch"),
        ({"policy_kwargs": {"activation_fn": "os.system"}}, "policy_kwargs.activation_fn"),
        ({"policy_kwargs": {"features_extractor_class": "x"}}, "policy_kwargs.features_extractor"),
        ({"policy_kwargs": {"n_critics": 2}}, "for PPO"),
        ({"observation_space": {"type": "Dict"}}, "key 'observation_space.spaces'"),
        ({"observation_space": {"type": "Tuple"}}, "key 'observation_space'"),
        ({"normalization": {"mean": [0.0], "var": [1.0], "epsilon": 1e-8, "clip_obs": 10}}, "16"),
        ({"policy_kwargs": {"net_arch": [32, 32]}}, "shape"),
        ({"algorithm": "SAC"}, "for SAC"),
        (
            {"algorithm": "SAC", "policy_kwargs": {"net_arch": [16, 16]}},
            "not those of the declared SAC policy",
        ),
    ],
)
def test_a_bad_declaration_is_one_clear_error(change, expected, tmp_path):
    directory = _declared(tmp_path)
    meta = json.loads((directory / "metadata.json").read_text()) | change
    (directory / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(PolicyLoadError) as caught:
        load_policy(read_metadata(directory))
    message = str(caught.value)
    assert expected in message and ("metadata.json" in message or "policy.pt" in message)
    assert "\n" not in message


def test_metadata_naming_sac_beside_a_ppo_zip_says_so(tmp_path):
    directory = _zip_only_model(tmp_path / "m")
    (directory / "metadata.json").write_text(json.dumps({"algorithm": "SAC"}))
    with pytest.raises(PolicyLoadError, match="says algorithm SAC, but model.zip holds a PPO"):
        load_policy(read_metadata(directory), trust_model=True)


def test_the_converter_needs_trust_and_writes_the_safe_form(tmp_path, capsys):
    directory = _zip_only_model(tmp_path / "m")
    assert convert_main([str(directory)]) == 2
    assert "--trust-model" in capsys.readouterr().err
    assert not (directory / "policy.pt").exists()
    assert convert_main([str(directory), "--trust-model"]) == 0
    metadata = read_metadata(directory)
    assert metadata.weights_file is not None and metadata.model_file == directory / "model.zip"
    safe, trusted = load_policy(metadata), load_trusted(metadata)
    _assert_same_actions(SB3Policy(safe.policy), SB3Policy(trusted.policy))


def test_a_policy_loaded_to_act_builds_no_torch_optimiser():
    """SB3 builds an optimiser with every policy; a torch optimiser's construction imports
    torch._dynamo (seconds of an evaluation's planning and of each worker). The safe loader
    builds the policy with a do-nothing optimiser, and the policy still acts."""
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from capture_bench.agents.sb3_policy import load_policy, read_metadata\n"
        "loaded = load_policy(read_metadata('models/dagger-dls-paper'))\n"
        "action, _ = loaded.policy.predict(np.zeros(16, np.float32), deterministic=True)\n"
        "assert action.shape == (3,), action.shape\n"
        "print('torch._dynamo' in sys.modules)\n"
    )
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"
