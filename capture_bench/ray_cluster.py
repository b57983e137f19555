"""Joining a Ray cluster for a command's workers (``evaluate.py --backend ray``, ``tune.py
--ray-address``): Ray imported only here and only when asked for (``pip install
capture-bench[ray]``), the cluster's address checked in seconds before any work, and Ray started
with this checkout shipped to the workers.

If Ray is already initialised in this process it is used as it is (its workers must be able to
import capture-bench: installed, or started from the checkout). Otherwise ``ray.init(address=...)``
starts a local instance (no address, or ``local``) or joins a cluster, shipping this checkout as
the job's ``working_dir`` (code, ``configs/``, ``models/``; not ``.git``, ``reports/``, ``runs/``);
the nodes need the dependencies installed, and a worker's working directory is that copy, not
the directory the command was started in.
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
    """The ``ray`` module; :class:`ConfigError` naming ``needed_by`` (an option) if it is not
    installed."""
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
    """Raise :class:`ConfigError` unless Ray can start for ``needed_by`` (the option asking for
    it, named in the messages): Ray is installed, and the cluster ``ray.init(address=address)``
    would join accepts a TCP connection within ``timeout_s`` seconds (Ray's own connect retries
    an unreachable address for many minutes).

    The address is resolved as ``ray.init`` resolves it (``RAY_ADDRESS``, ``auto``, a local host
    replaced by this node's IP). Nothing to reach when Ray is already initialised here or
    ``ray.init`` starts a local instance. A Ray Client address (``ray://HOST:PORT``) is left to
    Ray's client, which gives up by itself after about 30 s.
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


def start_ray(
    address: str | None, needed_by: str, log_to_driver: bool = False, excludes: Sequence[str] = ()
) -> bool:
    """Make Ray ready for this process's tasks: checked (:func:`check_ray_cluster`), then, unless
    it is already initialised here, started or joined at ``address`` with this checkout (less
    :data:`RAY_EXCLUDES` and ``excludes``, gitignore patterns relative to it) as the job's
    ``working_dir``, the workers' output shown here if ``log_to_driver``; Ray's own log lines
    below warnings are not printed. Return whether it was started here (then the caller shuts it
    down)."""
    ray = import_ray(needed_by)
    check_ray_cluster(address, needed_by)
    if ray.is_initialized():
        return False
    ray.init(
        address=address,
        include_dashboard=False,
        log_to_driver=log_to_driver,
        logging_level=logging.WARNING,
        runtime_env={"working_dir": str(CHECKOUT_DIR), "excludes": [*RAY_EXCLUDES, *excludes]},
    )
    return True
