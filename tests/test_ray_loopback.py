"""Ray on this machine (`capture_bench.ray_cluster`): a command given no cluster address
(``evaluate.py --backend ray``, the training sweep, ``tune.py --ray-address local``) starts a new
Ray instance, never the cluster recorded in Ray's temporary folder (a dead one here), with its
node registered at 127.0.0.1 and every server of it listening on the loopback only; a cluster
that cannot be reached stops the sweep in one line, exit status 2."""

from __future__ import annotations

import importlib.util
import ipaddress
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from capture_bench import ray_cluster
from tests.processes import descendants

ROOT = Path(__file__).resolve().parents[1]
needs_ray = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="Ray is not installed (pip install 'capture-bench[ray]')",
)
#: The cluster recorded in Ray's temporary folder: nothing answers there.
DEAD = "127.0.0.1:1"


@pytest.fixture(scope="module")
def recorded_dead_cluster():
    """Ray's temporary folder (``RAY_TMPDIR``, a new one) holding a cluster's address as ``ray
    start`` records it for ``ray.init()`` and ``ray.init(address="auto")`` to join: ``DEAD``."""
    # short: Ray's Unix socket paths live under it (at most 107 characters)
    temp = Path(tempfile.mkdtemp(prefix="cb-ray-", dir="/tmp"))
    (temp / "ray").mkdir()
    (temp / "ray" / "ray_current_cluster").write_text(DEAD)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("RAY_TMPDIR", str(temp))
        patch.delenv("RAY_ADDRESS", raising=False)
        yield temp
    shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture(scope="module")
def local_ray(recorded_dead_cluster):
    """Ray started here as a command given no address starts it (``start_ray(None, ...)``), shut
    down after the module's tests."""
    ray = pytest.importorskip("ray")
    # the checkout is shipped to the workers; the models are not needed there
    started = ray_cluster.start_ray(None, "the test", excludes=["/models", "/docs"])
    try:
        assert started and ray.is_initialized()
        yield ray
    finally:
        ray.shutdown()


def _socket_inodes(pids: list[int]) -> set[str]:
    inodes = set()
    for pid in pids:
        try:
            fds = list(Path(f"/proc/{pid}/fd").iterdir())
        except OSError:  # ended meanwhile
            continue
        for fd in fds:
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith("socket:["):
                inodes.add(target[len("socket:[") : -1])
    return inodes


def _hex_ip(text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    """An address as /proc/net/tcp{,6} writes it: 32-bit words in host order (little-endian)."""
    raw = bytes.fromhex(text)
    return ipaddress.ip_address(b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4)))


def listening(pids: list[int]) -> list[tuple[str, int]]:
    """``(IP, port)`` of every TCP socket that processes ``pids`` listen on (/proc, Linux)."""
    inodes = _socket_inodes(pids)
    found = []
    for table in ("tcp", "tcp6"):
        path = Path("/proc/net") / table
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            local, state, inode = fields[1], fields[3], fields[9]
            if state == "0A" and inode in inodes:  # 0A: LISTEN
                host, port = local.split(":")
                found.append((str(_hex_ip(host)), int(port, 16)))
    return found


def is_loopback(ip: str) -> bool:
    address = ipaddress.ip_address(ip)
    mapped = getattr(address, "ipv4_mapped", None)  # ::ffff:127.0.0.1
    return address.is_loopback or (mapped is not None and mapped.is_loopback)


@needs_ray
def test_a_local_start_does_not_join_the_cluster_recorded_in_rays_temporary_folder(
    local_ray, recorded_dead_cluster
):
    ray = local_ray
    gcs = ray.get_runtime_context().gcs_address
    assert gcs != DEAD and not gcs.endswith(":1"), gcs
    assert [n["Alive"] for n in ray.nodes()] == [True]  # its own node, up
    sessions = list((recorded_dead_cluster / "ray").glob("session_*"))
    assert sessions, "the new instance keeps its files in the given temporary folder"
    assert (recorded_dead_cluster / "ray" / "ray_current_cluster").read_text() == DEAD


@needs_ray
def test_the_local_instance_is_registered_and_listens_on_the_loopback_only(local_ray):
    ray = local_ray
    assert [n["NodeManagerAddress"] for n in ray.nodes()] == ["127.0.0.1"]
    assert ray.util.get_node_ip_address() == "127.0.0.1"
    assert ray.get_runtime_context().gcs_address.startswith("127.0.0.1:")
    task = ray.remote(num_cpus=1)(ray.util.get_node_ip_address)
    assert ray.get(task.remote(), timeout=120) == "127.0.0.1"  # a worker's view too
    sockets = listening([os.getpid(), *descendants(os.getpid())])
    assert sockets, "no listening socket found for Ray's processes"
    assert [s for s in sockets if not is_loopback(s[0])] == [], sockets


def test_no_address_looks_at_no_cluster(recorded_dead_cluster, monkeypatch):
    """No address (or ``local``) is a new local instance: neither the cluster recorded in Ray's
    temporary folder nor ``RAY_ADDRESS``'s (both dead here) is checked or joined."""
    ray = pytest.importorskip("ray")
    monkeypatch.setattr(ray, "is_initialized", lambda: False)  # as in a command's own process
    monkeypatch.setenv("RAY_ADDRESS", DEAD)
    ray_cluster.check_ray_cluster(None, "the test")
    ray_cluster.check_ray_cluster("local", "the test")


@needs_ray
@pytest.mark.parametrize("address", ["127.0.0.1:1", "ray://127.0.0.1:1"])
def test_a_sweep_that_cannot_reach_its_cluster_is_one_line_and_exit_2(tmp_path, address):
    """In a child process, as a user runs it: a hang or a traceback fails the test."""
    runs = tmp_path / "runs"
    done = subprocess.run(
        [sys.executable, "-m", "capture_bench", "sweep", "--algos", "ppo", "--scenarios",
         "paper", "--seeds", "0", "--runs", str(runs), "--ray-address", address],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr[-3000:]
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sweep: error: "), lines
    assert address in lines[0] and "no Ray cluster answers" in lines[0], lines
    assert not runs.exists()
