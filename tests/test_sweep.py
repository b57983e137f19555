"""``python -m capture_bench sweep``: training runs as Ray tasks on a real two-node Ray cluster
(a head and a worker, each its own ``ray start`` process on this machine), the run directories
sent back to the driver's ``--runs``, a sweep that resumes where it stopped, a run that fails
without stopping the others, and bad input refused in one line before any work."""

from __future__ import annotations

import importlib.util
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pytest

from capture_bench.training.sweep.command import SUMMARY_FILE, main, parse_seeds
from capture_bench.validation import ConfigError
from tests.processes import alive, descendants

ROOT = Path(__file__).resolve().parents[1]
needs_ray = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="Ray is not installed (pip install 'capture-bench[ray]')",
)
TINY = ["n_envs=2", "n_steps=32", "eval_freq=64", "eval_episodes=2", "checkpoint_freq=64",
        "policy_kwargs.net_arch=[8]"]  # fmt: skip
SET = [f"--set={item}" for item in TINY]
#: Seconds a node's `ray start` has to come up, a sweep to end.
START_S, SWEEP_S = 120, 300


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@dataclass
class Cluster:
    address: str
    env: dict[str, str]


def _start_node(args: list[str], log: Path, env: dict[str, str]) -> subprocess.Popen:
    """``ray start ... --block`` in its own session, its output in ``log``; returns once it says
    the node runs."""
    with log.open("w") as out:
        node = subprocess.Popen(
            [sys.executable, "-m", "ray.scripts.scripts", "start", "--block", *args],
            stdout=out, stderr=subprocess.STDOUT, env=env, start_new_session=True,
        )  # fmt: skip
    deadline = time.monotonic() + START_S
    while "Ray runtime started" not in log.read_text():
        if node.poll() is not None or time.monotonic() > deadline:
            _stop([node])
            pytest.fail(f"`ray start {' '.join(args)}` did not start:\n{log.read_text()[-3000:]}")
        time.sleep(0.2)
    return node


def _stop(nodes: list[subprocess.Popen]) -> list[int]:
    """End the nodes (SIGTERM: `ray start --block` then ends every process it started) and
    return the processes of theirs still alive after 60 s (killed by then)."""
    started = [n.pid for n in nodes] + [p for n in nodes for p in descendants(n.pid)]
    for node in nodes:
        if node.poll() is None:
            node.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + 60
    for node in nodes:
        try:
            node.wait(timeout=max(deadline - time.monotonic(), 1))
        except subprocess.TimeoutExpired:
            pass
    while [p for p in started if alive(p)] and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [p for p in started if alive(p)]
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    return left


#: The nodes' address: on the loopback, not the machine's network address (which Ray takes for
#: 127.0.0.1, and which some machines refuse connections to). Ray keeps a node at 127.0.0.1 only
#: with multi-machine clusters off, and then refuses to start a second node.
NODE_IP = "127.0.0.2"


@pytest.fixture(scope="module")
def cluster():
    """A Ray cluster of two nodes with one CPU each: a head and a worker, each started by its own
    ``ray start`` process with its own temporary folder, both registered at `NODE_IP`,
    token authentication on (a token made for it). Every process the two started has ended after
    the module's tests."""
    if importlib.util.find_spec("ray") is None:
        pytest.skip("Ray is not installed (pip install 'capture-bench[ray]')")
    # short: Ray's Unix socket paths live under it (at most 107 characters)
    temp = Path(tempfile.mkdtemp(prefix="cb-ray-", dir="/tmp"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    env |= {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32),
            "RAY_USAGE_STATS_ENABLED": "0", "PYTHONPATH": str(ROOT)}  # fmt: skip
    port = _free_port()
    node_args = ["--num-cpus=1", "--disable-usage-stats", f"--node-ip-address={NODE_IP}"]
    nodes = []

    def ports() -> list[str]:  # two nodes on one machine: each its own agents' ports
        return [f"--dashboard-agent-listen-port={_free_port()}",
                f"--runtime-env-agent-port={_free_port()}",
                f"--metrics-export-port={_free_port()}"]  # fmt: skip

    try:
        head = ["--head", f"--port={port}", f"--ray-client-server-port={_free_port()}",
                "--include-dashboard=false", f"--temp-dir={temp / 'head'}"]  # fmt: skip
        nodes.append(_start_node([*head, *node_args, *ports()], temp / "head.log", env))
        worker = [f"--address={NODE_IP}:{port}", f"--temp-dir={temp / 'worker'}"]
        nodes.append(_start_node([*worker, *node_args, *ports()], temp / "worker.log", env))
        yield Cluster(f"{NODE_IP}:{port}", env)
    finally:
        left = _stop(nodes)
        shutil.rmtree(temp, ignore_errors=True)
        assert not left, f"Ray processes outlived their `ray start`: {left}"


def sweep(cluster: Cluster, *argv: str) -> subprocess.CompletedProcess:
    """The command, as a user runs it, against the cluster."""
    return subprocess.run(
        [sys.executable, "-m", "capture_bench", "sweep", *argv, "--ray-address", cluster.address],
        cwd=ROOT, env=cluster.env, capture_output=True, text=True, timeout=SWEEP_S,
    )  # fmt: skip


def summary(runs: Path) -> dict:
    return json.loads((runs / SUMMARY_FILE).read_text())


@needs_ray
def test_every_run_lands_under_the_drivers_runs_from_both_nodes(cluster, tmp_path):
    runs = tmp_path / "runs"
    done = sweep(cluster, "--algos", "ppo", "a2c", "--scenarios", "paper", "--seeds", "0-1",
                 "--total-timesteps", "128", "--runs", str(runs), *SET)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    names = {f"paper-{a}-{s}" for a in ("ppo", "a2c") for s in (0, 1)}
    assert {p.name for p in runs.iterdir()} == names | {SUMMARY_FILE}  # no staging folder left
    for name in names:
        run = runs / name
        for file in ("policy.pt", "metadata.json", "model.zip", "validations.csv"):
            assert (run / file).is_file(), (name, file)
        assert (run / "checkpoints" / "step_128" / "parameters.pt").is_file()
        meta = json.loads((run / "metadata.json").read_text())
        assert meta["total_timesteps"] == 128 and meta["seed"] == int(name[-1])
        assert meta["algorithm"] == name.split("-")[1].upper()
        config = json.loads((run / "config.json").read_text())["config"]
        assert config["run_dir"] == str(run)  # where it is now, not the node's temporary folder
    report = summary(runs)
    assert [r["outcome"] for r in report["runs"]] == ["trained"] * 4
    used = {r["node_id"] for r in report["runs"]}
    assert used == set(report["nodes"])
    assert {n["ip"] for n in report["nodes"].values()} == {NODE_IP}  # on the loopback
    assert any(not report["nodes"][n]["head"] for n in used), "no run ran on the worker node"


def _interrupted_run(run_dir: Path) -> None:
    """train.py stopped by Ctrl-C at step 64 of 128: it saves a checkpoint and exits 130."""
    from capture_bench.training import callbacks
    from capture_bench.training.common.run import main as train

    original = callbacks.Progress._on_step

    def ctrl_c_at_64(self):
        if self.num_timesteps >= 64:
            raise KeyboardInterrupt
        return original(self)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(callbacks.Progress, "_on_step", ctrl_c_at_64)
        argv = ["--algo", "ppo", "--seed", "1", "--total-timesteps", "128",
                "--run-dir", str(run_dir), *SET]  # fmt: skip
        assert train(argv) == 130


@pytest.fixture(scope="module")
def rerun(cluster, tmp_path_factory):
    """A sweep of PPO on paper and grasp from seeds 0-2, run where an earlier one stopped:
    paper-ppo-0 finished, paper-ppo-1 interrupted at step 64 of 128 (train.py, here). Its
    ``--config`` sets ``batch_size: 1`` on grasp only, a valid hyper-parameter that SB3's PPO
    refuses when the model is built, on the node: every grasp run fails there.

    Returns (the runs folder, the command's result, the files of paper-ppo-0 and those of
    paper-ppo-1 before)."""
    from capture_bench.training.common.run import main as train

    root = tmp_path_factory.mktemp("rerun")
    runs = root / "runs"
    argv = ["--algo", "ppo", "--seed", "0", "--total-timesteps", "128", *SET]
    assert train([*argv, "--run-dir", str(runs / "paper-ppo-0")]) == 0
    _interrupted_run(runs / "paper-ppo-1")
    before = [{p.relative_to(runs): p.read_bytes() for p in (runs / name).rglob("*") if p.is_file()}
              for name in ("paper-ppo-0", "paper-ppo-1")]  # fmt: skip
    config = root / "grasp_fails.yaml"
    config.write_text("grasp:\n  batch_size: 1\n")
    done = sweep(cluster, "--algos", "ppo", "--scenarios", "paper", "grasp", "--seeds", "0-2",
                 "--total-timesteps", "128", "--config", str(config), "--runs", str(runs),
                 *SET)  # fmt: skip
    return runs, done, *before


@needs_ray
def test_a_sweep_run_again_keeps_finished_runs_and_resumes_an_interrupted_one(rerun):
    runs, done, finished, interrupted = rerun
    report = {r["name"]: r for r in summary(runs)["runs"]}
    assert report["paper-ppo-0"]["outcome"] == "kept", done.stdout
    assert report["paper-ppo-1"]["outcome"] == "resumed"
    assert report["paper-ppo-1"]["resumed_from"] == 64
    assert report["paper-ppo-2"]["outcome"] == "trained"
    now = {p.relative_to(runs): p.read_bytes() for p in runs.rglob("*") if p.is_file()}
    assert {p: now[p] for p in finished} == finished  # kept as it was
    # the resumed run went on from its checkpoint: the first session's files (its step_64
    # checkpoint, its TensorBoard events) are there unchanged, beside the second session's
    step_64 = Path("paper-ppo-1/checkpoints/step_64/parameters.pt")
    assert now[step_64] == interrupted[step_64]
    events = {p for p in interrupted if p.name.startswith("events.out.tfevents")}
    assert events and {p: now[p] for p in events} == {p: interrupted[p] for p in events}
    assert Path("paper-ppo-1/checkpoints/step_128/parameters.pt") in now
    meta = json.loads((runs / "paper-ppo-1" / "metadata.json").read_text())
    assert meta["total_timesteps"] == 128 and meta["seed"] == 1
    assert (runs / "paper-ppo-2" / "metadata.json").is_file()


@needs_ray
def test_failing_runs_are_reported_with_their_error_and_the_others_complete(rerun):
    runs, done, *_ = rerun
    assert done.returncode == 1, done.stderr[-3000:]
    report = {r["name"]: r for r in summary(runs)["runs"]}
    for seed in (0, 1, 2):
        failed = report[f"grasp-ppo-{seed}"]
        assert failed["outcome"] == "failed"
        assert failed["error"].startswith("AssertionError: `batch_size` must be greater than 1")
        assert "Traceback" in failed["output"]  # the end of train.py's output on the node
        assert f"sweep: grasp-ppo-{seed} failed: {failed['error']}" in done.stderr
        assert not (runs / f"grasp-ppo-{seed}").exists()  # no checkpoint: nothing to resume
    assert {report[f"paper-ppo-{s}"]["outcome"] for s in (0, 1, 2)} <= {
        "kept",
        "resumed",
        "trained",
    }
    assert sorted(p.name for p in runs.iterdir()) == [
        "paper-ppo-0", "paper-ppo-1", "paper-ppo-2", SUMMARY_FILE
    ]  # fmt: skip


def test_a_gpu_asked_of_a_cluster_without_one_is_refused(monkeypatch):
    """Ray would wait forever for a node with a GPU: the sweep is refused first."""
    from capture_bench.training.sweep.driver import check_resources

    nodes = [{"Alive": True, "Resources": {"CPU": 4.0}},
             {"Alive": True, "Resources": {"CPU": 2.0, "GPU": 1.0}},
             {"Alive": False, "Resources": {"CPU": 8.0, "GPU": 8.0}}]  # fmt: skip
    monkeypatch.setitem(sys.modules, "ray", SimpleNamespace(nodes=lambda: nodes))
    check_resources(2, 1)
    check_resources(4, 0)
    with pytest.raises(ConfigError, match="its nodes: 2 CPU / 1 GPU, 4 CPU / 0 GPU"):
        check_resources(4, 1)
    with pytest.raises(ConfigError, match="--gpus-per-run 2"):
        check_resources(1, 2)


def test_seeds_are_numbers_and_ranges_in_order_each_once():
    assert parse_seeds(["0-2", "5", "7,1", "2"]) == [0, 1, 2, 5, 7]
    for bad in ("3-1", "x", "1-", "-1"):
        with pytest.raises(ConfigError):
            parse_seeds([bad])


BASE = ["--algos", "ppo", "--scenarios", "paper", "--seeds", "0"]


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--algos", "dqn", "--scenarios", "paper", "--seeds", "0"], "invalid choice: 'dqn'"),
        (["--algos", "ppo", "--scenarios", "nowhere", "--seeds", "0"], "no such scenario"),
        (["--algos", "ppo", "--scenarios", "paper", "--seeds", "3-1"], "--seeds 3-1"),
        (["--algos", "ppo", "--scenarios", "paper", "--seeds", "1000000"], "evaluation seeds"),
        ([*BASE, "--set", "gama=0.9"], "ppo on paper: --set gama=0.9: unknown key"),
        ([*BASE, "--device", "cuda"], "--gpus-per-run"),
        ([*BASE, "--config", "/nonexistent.yaml"], "--config /nonexistent.yaml"),
        ([*BASE, "--ray-address", "127.0.0.1:1"], "no Ray cluster answers at"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, argv, expected):
    if "--ray-address" in argv and importlib.util.find_spec("ray") is None:
        pytest.skip("Ray is not installed (pip install 'capture-bench[ray]')")
    runs = tmp_path / "runs"
    assert main([*argv, "--runs", str(runs)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and expected in err, err
    assert "Traceback" not in err and not runs.exists()


def test_without_ray_the_sweep_is_refused_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    runs = tmp_path / "runs"
    assert main([*BASE, "--runs", str(runs), *SET]) == 2
    err = capsys.readouterr().err
    assert err == "sweep: error: the sweep needs Ray: pip install 'capture-bench[ray]'\n"
    assert not runs.exists()


def test_a_folder_in_the_way_that_is_not_a_run_is_refused(tmp_path, capsys):
    runs = tmp_path / "runs"
    (runs / "paper-ppo-0").mkdir(parents=True)
    (runs / "paper-ppo-0" / "notes.txt").write_text("mine")
    assert main([*BASE, "--runs", str(runs)]) == 2
    err = capsys.readouterr().err
    assert "not a run of train.py" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in runs.rglob("*")) == ["notes.txt", "paper-ppo-0"]
