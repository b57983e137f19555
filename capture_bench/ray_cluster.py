"""Joining a Ray cluster (or starting a local one) for the commands that run work on Ray: the
evaluation's ``ray`` backend and the training sweep.

Ray is imported only here and by the work sent to it (``pip install capture-bench[ray]``). If
Ray is already initialised in this process it is used as it is (its workers must be able to
import capture-bench: installed, or started from the checkout). Otherwise :func:`init` starts a
local instance (no address) or joins a cluster, shipping this checkout as the job's
``working_dir`` (code and ``configs/``; not ``.git``, ``reports/``, ``runs/``), so every node
runs the code this process runs; the nodes need the dependencies installed.
:func:`check_ray_cluster` refuses a cluster that does not answer, in seconds: Ray itself retries
an unreachable address for many minutes.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Sequence
from typing import Any

from capture_bench.paths import CHECKOUT_DIR
from capture_bench.validation import ConfigError

#: Not shipped to Ray workers with the checkout.
RAY_EXCLUDES = [".git", "reports", "runs", "**/__pycache__", "*.egg-info", ".venv", "*.png"]

#: Seconds the Ray cluster's address has to accept a TCP connection before the run is refused.
RAY_CONNECT_TIMEOUT_S = 5.0


def import_ray(needed_by: str) -> Any:
    """The ``ray`` module; :class:`ConfigError` naming ``needed_by`` (``--backend ray``) and the
    extra to install where Ray is not installed."""
    try:
        import ray
    except ImportError:
        raise ConfigError(f"{needed_by} needs Ray: pip install 'capture-bench[ray]'") from None
    return ray


def _host_port(address: str, source: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    if not (host and port.isascii() and port.isdigit() and 0 < int(port) < 65536):
        raise ConfigError(
            f"{source}: expected HOST:PORT (the address `ray start --head` prints), auto, or "
            "ray://HOST:PORT"
        )
    return host.strip("[]"), int(port)


def check_ray_cluster(
    address: str | None, needed_by: str, timeout_s: float = RAY_CONNECT_TIMEOUT_S
) -> None:
    """Raise :class:`ConfigError` unless Ray can start: Ray is installed, and the cluster
    ``ray.init(address=address)`` would join accepts a TCP connection within ``timeout_s``
    seconds (Ray's own connect retries an unreachable address for many minutes).

    The address is resolved as ``ray.init`` resolves it (``RAY_ADDRESS``, ``auto``, a local host
    replaced by this node's IP). Nothing to reach when Ray is already initialised here or
    ``ray.init`` starts a local instance. A Ray Client address (``ray://HOST:PORT``) is left to
    Ray's client, which gives up by itself after about 30 s.

    Args:
        address: the ``--ray-address`` given, or None.
        needed_by: the option that asks for Ray, for the messages (``--backend ray``).
        timeout_s: how long the cluster has to accept a connection.
    """
    ray = import_ray(needed_by)
    if ray.is_initialized():
        return
    from ray._private.services import canonicalize_bootstrap_address  # what ray.init calls

    env = os.environ.get("RAY_ADDRESS") if address in (None, "auto") else None
    given = env or address
    source = f"RAY_ADDRESS={env}" if env else f"--ray-address {address}"
    if given is not None and "://" in given:
        return
    if given not in (None, "auto", "local"):
        _host_port(given, source)  # checked here: Ray logs a traceback for some malformed ones
    try:
        # typed as str, but ray.init passes None too (RAY_ADDRESS, or a local instance)
        target = canonicalize_bootstrap_address(given)  # type: ignore[arg-type]
    except ConnectionError:  # auto, and no cluster started here with `ray start`
        raise ConfigError(
            f"{source}: no Ray cluster runs on this machine; start one with `ray start --head` "
            "or give a cluster's address"
        ) from None
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    if target is None:
        return
    if given is None:
        source = f"{needed_by} with no --ray-address (the cluster `ray start` last started here)"
    host, port = _host_port(target, source)
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the host name
        timed_out = isinstance(exc, TimeoutError)
        reason = f"no answer in {timeout_s:g} s" if timed_out else getattr(exc, "strerror", None)
        where = target if given in (None, target) else f"{target}, where Ray connects for {given}"
        raise ConfigError(
            f"{source}: no Ray cluster answers at {where} ({reason or exc}); start one with "
            "`ray start --head` or give a running cluster's address"
        ) from None


def init(address: str | None, needed_by: str, excludes: Sequence[str] = ()) -> bool:
    """Initialise Ray unless it already is here: join the cluster at ``address`` (checked first:
    :func:`check_ray_cluster`) or start a local instance (None), shipping this checkout (less
    :data:`RAY_EXCLUDES` and ``excludes``, gitignore patterns relative to it) as the job's
    ``working_dir``; Ray's own log lines below warnings are not printed. Returns whether this call
    initialised Ray (the caller then shuts it down)."""
    ray = import_ray(needed_by)
    check_ray_cluster(address, needed_by)
    if ray.is_initialized():
        return False
    runtime_env = {"working_dir": str(CHECKOUT_DIR), "excludes": [*RAY_EXCLUDES, *excludes]}
    ray.init(
        address=address,
        include_dashboard=False,
        log_to_driver=False,
        logging_level=logging.WARNING,
        runtime_env=runtime_env,
    )
    return True
