"""Client-leak tests: closing an environment disconnects every pybullet client it opened.

Every pybullet client is recorded as it connects (``BulletClient`` calls ``pybullet.connect``
through the module). The closed objects stay referenced until the check, so pybullet's own
``__del__`` cannot disconnect behind a ``close()`` that forgot to; the last test shows that the
check catches exactly that. Memory over 1,000 envs and 10,000 episodes:
``benchmarks/bench_resources.py``.
"""

from collections.abc import Callable, Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import pybullet
import pytest

from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.envs.vector_env import CaptureVectorEnv
from capture_bench.sim.target_motion import FEATURE_POINTS
from capture_bench.sim.world import World

ENV_ID = "CaptureBench/Paper-v1"


@pytest.fixture
def clients(monkeypatch) -> Iterator[list[int]]:
    """The id of every pybullet client connected during the test, in order."""
    ids: list[int] = []
    connect = pybullet.connect

    def recording_connect(*args, **kwargs):
        client = connect(*args, **kwargs)
        ids.append(client)
        return client

    monkeypatch.setattr(pybullet, "connect", recording_connect)
    yield ids


def connected(ids: list[int]) -> list[int]:
    """Those of ``ids`` that are connected now."""
    return sorted({c for c in ids if pybullet.isConnected(physicsClientId=c)})


def make_world() -> World:
    return World(FEATURE_POINTS["non_coplanar"])


def make_env() -> Any:
    return gym.make(ENV_ID)


def make_vector_env(mode: str = "vector_entry_point") -> Any:
    return gym.make_vec(ENV_ID, num_envs=3, vectorization_mode=mode)


def open_and_close(make: Callable[[], Any], count: int, clients: list[int]) -> list[Any]:
    """Make ``count`` objects, reset and step each (if it is an env) and close it twice; returns
    them, still alive, so that only their ``close()`` can have disconnected their clients."""
    closed = []
    for seed in range(count):
        opened = len(clients)
        thing = make()
        if hasattr(thing, "step"):
            thing.reset(seed=seed)
            action = np.zeros(thing.action_space.shape, dtype=np.float32)
            for _ in range(2):
                thing.step(action)
        assert connected(clients[opened:]) == clients[opened:] != []  # the probe sees it open
        thing.close()
        thing.close()  # safe twice
        closed.append(thing)
    return closed


def test_closing_30_single_envs_disconnects_every_client(clients):
    envs = open_and_close(make_env, 30, clients)
    assert len(envs) == len(clients) == 30  # one client per env
    assert connected(clients) == []


@pytest.mark.parametrize("mode", ["vector_entry_point", "sync"])
def test_closing_vector_envs_disconnects_every_client(clients, mode):
    open_and_close(lambda: make_vector_env(mode), 3, clients)
    assert connected(clients) == []


def test_closing_worlds_disconnects_their_clients(clients):
    open_and_close(make_world, 5, clients)
    assert connected(clients) == []


def test_reset_after_close_opens_a_client_that_close_disconnects(clients):
    (env,) = open_and_close(make_env, 1, clients)
    env.reset(seed=1)  # documented: reset() after close() opens a new world
    assert len(clients) == 2 and len(connected(clients)) == 1
    env.close()
    assert connected(clients) == []


@pytest.mark.parametrize(
    ("owner", "method", "make"),
    [
        (World, "close", make_world),
        (CaptureEnv, "close", make_env),
        (CaptureVectorEnv, "close_extras", make_vector_env),
    ],
)
def test_the_check_catches_a_close_that_forgets_to_disconnect(
    clients, monkeypatch, owner, method, make
):
    with monkeypatch.context() as patch:
        patch.setattr(owner, method, lambda self, **kwargs: None)
        things = open_and_close(make, 2, clients)
        leaked = connected(clients)
    for thing in things:  # the real one now, through the objects (pybullet reuses ids)
        getattr(getattr(thing, "unwrapped", thing), method)()
    assert leaked == sorted(set(clients)) != []
    assert connected(clients) == []
