"""Ray for a command's workers (``evaluate.py --backend ray``, the training sweep, ``tune.py
--ray-address``): Ray imported only here and only when asked for (``pip install
capture-bench[ray]``), a new local instance or the cluster the command was given, the cluster's
address checked in seconds before any work, and this checkout shipped to the workers.

Given no address (or ``local``), a command starts a new Ray instance on this machine
(`start_local_ray`): it never joins a cluster it was not given, neither the one ``ray
start`` recorded in Ray's temporary folder nor ``RAY_ADDRESS``'s, and its node is registered at
127.0.0.1 with its servers listening there only. Given an address (``HOST:PORT``, ``auto``: the
cluster ``RAY_ADDRESS`` names, else one running on this machine as Ray finds it, the one ``ray
start`` last started first; ``ray://HOST:PORT``), it joins that cluster only; one that does not
answer is refused in one line.

If Ray is already initialised in this process it is used as it is (its workers must be able to
import capture-bench: installed, or started from the checkout). Otherwise Ray is started or
joined with this checkout as the job's ``working_dir`` (code, ``configs/``, ``models/``; not
``.git``, ``reports/``, ``runs/``); the nodes need the dependencies installed, and a worker's
working directory is that copy, not the directory the command was started in.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
from collections.abc import Iterator, Sequence
from typing import Any

from capture_bench.paths import CHECKOUT_DIR
from capture_bench.validation import ConfigError

#: Not shipped to Ray workers with the checkout.
RAY_EXCLUDES = [".git", "reports", "runs", "**/__pycache__", "*.egg-info", ".venv", "*.png"]

#: Seconds the Ray cluster's address has to accept a TCP connection before the run is refused.
RAY_CONNECT_TIMEOUT_S = 5.0

#: Where a Ray instance started here registers its node and listens.
LOOPBACK = "127.0.0.1"

#: Ray's switch for clusters of several machines; off, Ray keeps a node's address on the loopback
#: (its default on macOS and Windows).
CLUSTERS_VARIABLE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"

#: The addresses that start a local instance instead of joining a cluster.
LOCAL = (None, "local")


def import_ray(needed_by: str) -> Any:
    """The ``ray`` module; [`ConfigError`][capture_bench.ConfigError] naming ``needed_by`` (an
    option) if it is not
    installed."""
    try:
        import ray
    except ImportError:
        raise ConfigError(f"{needed_by} needs Ray: pip install 'capture-bench[ray]'") from None
    return ray


@contextlib.contextmanager
def _clusters_off() -> Iterator[None]:
    """Ray with its multi-machine clusters off, in this process and in the processes it starts
    meanwhile (restored after). Ray replaces a node address of 127.0.0.1 by the machine's
    network address (``ray._private.services.resolve_ip_for_localhost``) unless clusters are off
    (``ray_constants.ENABLE_RAY_CLUSTER``, read when called; ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER``
    in the environment, read when Ray is imported). A node at 127.0.0.1 has its servers listen
    on 127.0.0.1 only; at any other address they listen on every interface."""
    from ray._private import ray_constants

    saved_flag = ray_constants.ENABLE_RAY_CLUSTER
    saved_variable = os.environ.get(CLUSTERS_VARIABLE)
    ray_constants.ENABLE_RAY_CLUSTER = False
    os.environ[CLUSTERS_VARIABLE] = "0"
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = saved_flag
        if saved_variable is None:
            os.environ.pop(CLUSTERS_VARIABLE, None)
        else:
            os.environ[CLUSTERS_VARIABLE] = saved_variable


def start_local_ray(needed_by: str = "a local Ray instance", **options: Any) -> None:
    """Start a new Ray instance on this machine for this process, every local start's one way:
    ``ray.init(address="local")``, which reads neither ``RAY_ADDRESS`` nor the cluster recorded
    in Ray's temporary folder, so it never joins a cluster; its node registered at
    `LOOPBACK`, its servers listening there only; no dashboard. ``options``: ``ray.init``'s
    other arguments (``num_cpus``, ``log_to_driver``, ``runtime_env``, ``_temp_dir``, ...).
    The caller shuts it down (``ray.shutdown()``)."""
    ray = import_ray(needed_by)
    with _clusters_off():
        ray.init(address="local", _node_ip_address=LOOPBACK, include_dashboard=False, **options)


def _host_port(address: str, source: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    if not (host and port.isascii() and port.isdigit() and 0 < int(port) < 65536):
        raise ConfigError(
            f"{source}: expected HOST:PORT (the address `ray start --head` prints), auto, "
            "ray://HOST:PORT or local"
        )
    return host.strip("[]"), int(port)


def _is_local(address: str | None) -> bool:
    """Whether ``address`` starts a local instance: none, ``local``, or ``auto`` with
    ``RAY_ADDRESS=local``."""
    return address in LOCAL or (address == "auto" and os.environ.get("RAY_ADDRESS") == "local")


def _given(address: str) -> tuple[str, str]:
    """The address ``ray.init(address=address)`` joins before it is resolved (``auto``:
    ``RAY_ADDRESS`` if set), and how to name it in a message."""
    env = os.environ.get("RAY_ADDRESS") if address == "auto" else None
    if env:
        return env, f"RAY_ADDRESS={env}"
    return address, f"--ray-address {address}"


def check_ray_cluster(
    address: str | None, needed_by: str, timeout_s: float = RAY_CONNECT_TIMEOUT_S
) -> None:
    """Raise [`ConfigError`][capture_bench.ConfigError] unless Ray can start for ``needed_by`` (the
    option asking for
    it, named in the messages): Ray is installed, and the cluster at ``address`` accepts a TCP
    connection within ``timeout_s`` seconds (Ray's own connect retries an unreachable address
    for many minutes, its client for 30 s).

    The address is resolved as ``ray.init`` resolves it (``auto``: ``RAY_ADDRESS``, else the
    cluster ``ray start`` recorded in Ray's temporary folder, or one whose server runs on this
    machine; a local host replaced by this node's IP); a Ray Client address
    (``ray://HOST:PORT``) is checked as it is. Nothing to reach
    when Ray is already initialised here or there is no address (or ``local``): a local
    instance is started.
    """
    ray = import_ray(needed_by)
    if ray.is_initialized() or address is None or _is_local(address):
        return
    from ray._private.services import canonicalize_bootstrap_address  # what ray.init calls

    given, source = _given(address)
    scheme, _, rest = given.rpartition("://")
    if scheme and scheme != "ray":
        return  # another client protocol: Ray's to check
    if scheme:  # the Ray Client connects to the address as it is
        host, port = _host_port(rest, source)
        where = given
    else:
        if given != "auto":
            _host_port(given, source)  # checked here: Ray logs a traceback for some malformed ones
        try:
            target = canonicalize_bootstrap_address(given)
        except ConnectionError:  # auto, and no cluster started here with `ray start`
            raise ConfigError(
                f"{source}: no Ray cluster runs on this machine; start one with `ray start "
                "--head` or give a cluster's address"
            ) from None
        except ValueError as exc:
            raise ConfigError(f"{source}: {exc}") from None
        if target is None:  # a local instance after all
            return
        host, port = _host_port(target, source)
        where = target if given == target else f"{target}, where Ray connects for {given}"
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the host name
        timed_out = isinstance(exc, TimeoutError)
        reason = f"no answer in {timeout_s:g} s" if timed_out else getattr(exc, "strerror", None)
        raise ConfigError(
            f"{source}: no Ray cluster answers at {where} ({reason or exc}); start one with "
            "`ray start --head` or give a running cluster's address"
        ) from None


def start_ray(
    address: str | None, needed_by: str, log_to_driver: bool = False, excludes: Sequence[str] = ()
) -> bool:
    """Make Ray ready for this process's tasks: checked (`check_ray_cluster`), then, unless
    it is already initialised here, a new local instance started (`start_local_ray`; no
    ``address``, or ``local``) or the cluster at ``address`` joined, with this checkout (less
    `RAY_EXCLUDES` and ``excludes``, gitignore patterns relative to it) as the job's
    ``working_dir``, the workers' output shown here if ``log_to_driver``; Ray's own log lines
    below warnings are not printed. Return whether it was started here (then the caller shuts it
    down).

    Raises:
        ConfigError: Ray is not installed, or the cluster cannot be reached or joined.
    """
    ray = import_ray(needed_by)
    check_ray_cluster(address, needed_by)
    if ray.is_initialized():
        return False
    options: dict[str, Any] = {
        "log_to_driver": log_to_driver,
        "logging_level": logging.WARNING,
        "runtime_env": {
            "working_dir": str(CHECKOUT_DIR),
            "excludes": [*RAY_EXCLUDES, *excludes],
        },
    }
    if address is None or _is_local(address):
        start_local_ray(needed_by, **options)
        return True
    try:
        ray.init(address=address, include_dashboard=False, **options)
    except (ConnectionError, TimeoutError) as exc:  # it answered the check, then not Ray's way
        with contextlib.suppress(Exception):
            ray.shutdown()
        reason = " ".join(str(exc).split()) or type(exc).__name__
        source = _given(address)[1]
        raise ConfigError(f"{source}: Ray could not join the cluster ({reason})") from None
    return True
