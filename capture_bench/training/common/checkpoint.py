"""Training checkpoints that resume without unpickling anything.

SB3's own checkpoints (``model.save``, ``save_replay_buffer``, ``VecNormalize.save``) are pickles,
and unpickling a file runs whatever code its author put in it; a run directory someone hands you
to ``--resume`` must not be able to do that. A checkpoint at N environment steps is a directory
``step_<N>/`` holding

* ``parameters.pt``: every ``state_dict`` SB3 saves for the algorithm (policy, optimisers) and
  its torch variables (SAC's ``log_ent_coef``), read with ``torch.load(..., weights_only=True)``;
* ``state.json``: the counters (``num_timesteps``, ``_n_updates``, ``_episode_num``), the
  VecNormalize statistics as plain numbers, the replay buffer's position;
* ``replay_buffer.npz`` (off-policy algorithms): the buffer's arrays, read with
  ``allow_pickle=False``.

The directory is written under a temporary name and renamed into place, so a ``step_<N>/`` that
exists is complete. Resuming builds the model from the run's saved configuration, exactly as a
fresh run does, and `restore` fills it in.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "capture-bench-checkpoint/1"
PARAMETERS_FILE = "parameters.pt"
STATE_FILE = "state.json"
BUFFER_FILE = "replay_buffer.npz"
STEP_DIR = re.compile(r"^step_(\d+)$")
#: Replay-buffer arrays saved (those present on the buffer).
BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")
_COUNTERS = ("num_timesteps", "_n_updates", "_episode_num")


class CheckpointError(ValueError):
    """A checkpoint cannot be used; the message names the file and what is wrong."""


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint read and validated (nothing unpickled).

    Attributes:
        directory: the ``step_<N>`` directory.
        steps: environment steps it was taken at.
        state: the parsed ``state.json``.
        parameters: ``{"state_dicts": {name: state_dict}, "variables": {name: tensor}}``.
        buffer: the replay buffer's arrays, or None.
    """

    directory: Path
    steps: int
    state: dict[str, Any]
    parameters: dict[str, Any]
    buffer: dict[str, np.ndarray] | None


def step_directory(directory: Path, steps: int) -> Path:
    """Where the checkpoint at ``steps`` lives under a run's ``checkpoints/``."""
    return Path(directory) / f"step_{steps}"


def list_checkpoints(directory: Path) -> list[tuple[int, Path]]:
    """The complete checkpoints under ``directory``, oldest first, as ``(steps, path)``."""
    if not Path(directory).is_dir():
        return []
    found = []
    for path in Path(directory).iterdir():
        match = STEP_DIR.match(path.name)
        if match and path.is_dir() and (path / STATE_FILE).is_file():
            found.append((int(match.group(1)), path))
    return sorted(found)


# --------------------------------------------------------------------------- saving


def _vecnormalize_json(vecnormalize: Any) -> dict[str, Any]:
    def rms(stats: Any) -> dict[str, Any]:
        return {
            "mean": np.asarray(stats.mean, dtype=np.float64).ravel().tolist(),
            "var": np.asarray(stats.var, dtype=np.float64).ravel().tolist(),
            "count": float(stats.count),
        }

    return {
        "obs_rms": rms(vecnormalize.obs_rms),
        "ret_rms": rms(vecnormalize.ret_rms),
        "clip_obs": float(vecnormalize.clip_obs),
        "clip_reward": float(vecnormalize.clip_reward),
        "gamma": float(vecnormalize.gamma),
        "epsilon": float(vecnormalize.epsilon),
        "norm_obs": bool(vecnormalize.norm_obs),
        "norm_reward": bool(vecnormalize.norm_reward),
    }


def save_checkpoint(model: Any, directory: Path, replay_buffer: bool) -> Path:
    """Write the checkpoint of ``model`` at its ``num_timesteps`` into ``directory``.

    Args:
        model: the SB3 algorithm being trained.
        directory: the run's ``checkpoints/`` (created).
        replay_buffer: also save the replay buffer (off-policy algorithms).

    Returns:
        The ``step_<N>`` directory.
    """
    import torch

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    steps = int(model.num_timesteps)
    target = step_directory(directory, steps)
    tmp = directory / f".tmp-{os.getpid()}-{target.name}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    _, variable_names = model._get_torch_save_params()
    variables = {name: _attribute(model, name).detach().cpu().clone() for name in variable_names}
    buffer = io.BytesIO()
    torch.save({"state_dicts": model.get_parameters(), "variables": variables}, buffer)
    (tmp / PARAMETERS_FILE).write_bytes(buffer.getvalue())
    state: dict[str, Any] = {
        "format": FORMAT,
        "algorithm": type(model).__name__,
        "counters": {name: int(getattr(model, name)) for name in _COUNTERS},
        "vecnormalize": None,
        "replay_buffer": None,
    }
    stats = model.get_vec_normalize_env()
    if stats is not None:
        state["vecnormalize"] = _vecnormalize_json(stats)
    if replay_buffer:
        rb = model.replay_buffer
        arrays = {name: getattr(rb, name) for name in BUFFER_ARRAYS if hasattr(rb, name)}
        arrays = {k: v for k, v in arrays.items() if isinstance(v, np.ndarray)}
        with open(tmp / BUFFER_FILE, "wb") as handle:
            np.savez(handle, **arrays)
        state["replay_buffer"] = {"pos": int(rb.pos), "full": bool(rb.full)}
    (tmp / STATE_FILE).write_text(json.dumps(state, indent=2, allow_nan=False) + "\n")
    if target.exists():  # the same step saved again (Ctrl-C right after a periodic save)
        shutil.rmtree(target)
    os.replace(tmp, target)
    return target


def _attribute(obj: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj


# --------------------------------------------------------------------------- reading


def _number_list(value: Any) -> bool:
    return isinstance(value, list) and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value
    )


def _check_state(state: Any, where: Path) -> dict[str, Any]:
    def bad(key: str, valid: str) -> CheckpointError:
        return CheckpointError(f"{where}: key {key!r} is missing or invalid; valid: {valid}")

    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise bad("format", FORMAT)
    counters = state.get("counters")
    if not isinstance(counters, dict) or set(counters) != set(_COUNTERS):
        raise bad("counters", f"a mapping of {', '.join(_COUNTERS)} to integers >= 0")
    if not all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in counters.values()
    ):
        raise bad("counters", "integers >= 0")
    stats = state.get("vecnormalize")
    if stats is not None:
        ok = isinstance(stats, dict) and all(
            isinstance(stats.get(k), dict)
            and _number_list(stats[k].get("mean"))
            and _number_list(stats[k].get("var"))
            and isinstance(stats[k].get("count"), (int, float))
            for k in ("obs_rms", "ret_rms")
        )
        ok = ok and all(
            isinstance(stats.get(k), (int, float)) for k in ("clip_obs", "clip_reward", "gamma")
        )
        if not ok:
            raise bad("vecnormalize", "null or the statistics this module writes")
    rb = state.get("replay_buffer")
    if rb is not None and not (
        isinstance(rb, dict)
        and isinstance(rb.get("pos"), int)
        and rb["pos"] >= 0
        and isinstance(rb.get("full"), bool)
    ):
        raise bad("replay_buffer", "null or {pos: integer >= 0, full: true|false}")
    return state


def _check_archive(path: Path, what: str) -> None:
    """A checkpoint's archive (``parameters.pt``, ``replay_buffer.npz``) is a zip whose members
    are stored as they are, not compressed: refuse one that is not a zip, or that declares far
    more than it holds (a zip bomb), before torch or numpy allocates what it declares
    (`check_archive`). Their size on disk is not capped:
    a replay buffer is as large as the run chose (train.py's memory check bounds that)."""
    from capture_bench.agents.policy_file import PolicyLoadError, check_archive

    try:
        check_archive(path, capped=False)
    except PolicyLoadError as exc:
        detail = str(exc).removeprefix(f"{path}: ")
        raise CheckpointError(f"{path}: unreadable {what} ({detail})") from None


def read_checkpoint(directory: Path) -> Checkpoint:
    """Read and validate the checkpoint in ``directory`` (a ``step_<N>``); unpickles nothing.

    Raises:
        CheckpointError: a missing, unreadable or invalid file, named.
    """
    import torch

    directory = Path(directory)
    match = STEP_DIR.match(directory.name)
    if match is None or not directory.is_dir():
        raise CheckpointError(f"{directory}: not a checkpoint directory (step_<N>)")
    state_file = directory / STATE_FILE
    try:
        state = _check_state(json.loads(state_file.read_text()), state_file)
    except (OSError, ValueError) as exc:
        if isinstance(exc, CheckpointError):
            raise
        reason = " ".join(str(exc).split())
        raise CheckpointError(f"{state_file}: unreadable checkpoint state ({reason})") from None
    parameters_file = directory / PARAMETERS_FILE
    _check_archive(parameters_file, "parameters")
    try:
        parameters = torch.load(parameters_file, map_location="cpu", weights_only=True)
    except Exception as exc:  # missing, truncated, or refused by the weights-only reader
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CheckpointError(f"{parameters_file}: unreadable parameters ({reason})") from None
    if not (
        isinstance(parameters, dict)
        and isinstance(parameters.get("state_dicts"), dict)
        and isinstance(parameters.get("variables"), dict)
    ):
        raise CheckpointError(f"{parameters_file}: expected state_dicts and variables")
    buffer = None
    if state["replay_buffer"] is not None:
        buffer_file = directory / BUFFER_FILE
        _check_archive(buffer_file, "replay buffer")
        try:
            with np.load(buffer_file, allow_pickle=False) as archive:
                buffer = {name: archive[name] for name in archive.files}
        except Exception as exc:  # missing, truncated, or an object array (refused)
            reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise CheckpointError(f"{buffer_file}: unreadable replay buffer ({reason})") from None
    return Checkpoint(directory, int(match.group(1)), state, parameters, buffer)


# --------------------------------------------------------------------------- restoring


def _restore_vecnormalize(vecnormalize: Any, stats: dict[str, Any], where: Path) -> None:
    for name in ("obs_rms", "ret_rms"):
        rms = getattr(vecnormalize, name)
        mean = np.asarray(stats[name]["mean"], dtype=np.float64)
        if mean.size != np.asarray(rms.mean).size:
            raise CheckpointError(
                f"{where}: VecNormalize {name} has {mean.size} entries, the environment "
                f"{np.asarray(rms.mean).size}"
            )
        rms.mean = mean.reshape(np.shape(rms.mean))
        rms.var = np.asarray(stats[name]["var"], dtype=np.float64).reshape(np.shape(rms.var))
        rms.count = float(stats[name]["count"])
    for key in ("clip_obs", "clip_reward", "gamma", "epsilon", "norm_obs", "norm_reward"):
        setattr(vecnormalize, key, stats[key])


def restore(model: Any, checkpoint: Checkpoint) -> None:
    """Fill ``model`` (built from the run's configuration, with its envs) from ``checkpoint``.

    Raises:
        CheckpointError: the checkpoint does not fit the model (another algorithm or network,
            another buffer size, a missing VecNormalize).
    """
    where = checkpoint.directory
    if checkpoint.state["algorithm"] != type(model).__name__:
        raise CheckpointError(
            f"{where}: a {checkpoint.state['algorithm']} checkpoint, but the run trains "
            f"{type(model).__name__}"
        )
    try:
        model.set_parameters(checkpoint.parameters["state_dicts"], exact_match=True)
    except Exception as exc:  # SB3 raises ValueError/RuntimeError on a mismatch
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CheckpointError(
            f"{where}: parameters do not fit the run's model ({reason})"
        ) from None
    _, variable_names = model._get_torch_save_params()
    for name in variable_names:
        saved = checkpoint.parameters["variables"].get(name)
        current = _attribute(model, name)
        if saved is None or tuple(saved.shape) != tuple(current.shape):
            raise CheckpointError(f"{where}: torch variable {name!r} missing or misshapen")
        current.data.copy_(saved)
    for name, value in checkpoint.state["counters"].items():
        setattr(model, name, value)
    stats = checkpoint.state["vecnormalize"]
    vecnormalize = model.get_vec_normalize_env()
    if (stats is None) != (vecnormalize is None):
        raise CheckpointError(
            f"{where}: the checkpoint {'has' if stats else 'lacks'} VecNormalize statistics "
            f"but the run {'does not normalise' if stats else 'normalises'} observations"
        )
    if stats is not None:
        _restore_vecnormalize(vecnormalize, stats, where)
    if checkpoint.buffer is not None:
        rb = model.replay_buffer
        for name, array in checkpoint.buffer.items():
            current = getattr(rb, name, None)
            if not isinstance(current, np.ndarray) or current.shape != array.shape:
                raise CheckpointError(
                    f"{where}: replay buffer {name!r} has shape {array.shape}, the run's buffer "
                    f"{getattr(current, 'shape', None)} (buffer_size or n_envs changed?)"
                )
            current[...] = array
        rb.pos = checkpoint.state["replay_buffer"]["pos"]
        rb.full = checkpoint.state["replay_buffer"]["full"]
