"""DAgger's complete rounds on disk, so that a run stopped during its imitation goes on from its
last complete round (`capture_bench.training.common.imitation.dagger`).

After round r the store holds, under ``<run>/imitation_progress/``:

* ``round_<r>.npz``: the rows round r added to the data set: the observations (``obs``, or with
  pixels ``obs/<key>`` per key, images kept uint8), the teacher's labels (``labels``), with the
  state regression what the teacher read (``views``) and with the keypoint supervision the
  markers' image points (``points``);
* ``state.pt``: the policy's parameters after round r's fit (and the state regression's head),
  the rounds done and the log so far (fit losses, agreement, state errors, validations, wall
  clock), written after the rows and atomically, so it names only rounds whose rows are whole on
  disk; then ``rounds.json``, the count alone.

A resumed imitation loads the data set and the policy as they were and plays its next round on
freshly reset envs (the episodes in progress when it stopped are not continued: the rows it
gathers are DAgger's all the same, states the policy reaches, labelled by the teacher). The run
removes the store once a checkpoint holds the imitated policy (`RoundStore.clear`). A store that
cannot be read is a `CheckpointError` that says so; removing the folder starts the imitation
again.
"""

from __future__ import annotations

import json
import pickle
import shutil
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from capture_bench.files import atomic_write
from capture_bench.training.common.checkpoint import CheckpointError

#: The store's folder inside a run's directory.
ROUNDS_DIR = "imitation_progress"
_STATE = "state.pt"
_COUNT = "rounds.json"


@dataclass
class Progress:
    """What DAgger has done so far: ``rounds`` complete, the data set's ``observations``,
    ``labels``, ``views`` and ``points`` (batches: one per environment step as `dagger` gathers
    them, one per round as `RoundStore.load` gives them back), each round's ``losses``,
    ``state_losses``, ``keypoint_px``, ``agreement`` and ``curve`` (validations), and the wall
    clock ``elapsed_s`` spent on them."""

    rounds: int = 0
    observations: list[Any] = field(default_factory=list)
    labels: list[np.ndarray] = field(default_factory=list)
    views: list[np.ndarray] = field(default_factory=list)
    points: list[np.ndarray] = field(default_factory=list)
    losses: list[float] = field(default_factory=list)
    state_losses: list[float] = field(default_factory=list)
    keypoint_px: list[float] = field(default_factory=list)
    agreement: list[float | None] = field(default_factory=list)
    curve: list[dict[str, Any]] = field(default_factory=list)
    elapsed_s: float = 0.0

    def log(self) -> dict[str, Any]:
        return {
            "rounds": self.rounds,
            "losses": self.losses,
            "state_losses": self.state_losses,
            "keypoint_px": self.keypoint_px,
            "agreement": self.agreement,
            "curve": self.curve,
            "elapsed_s": self.elapsed_s,
        }


class RoundStore:
    """The complete rounds of one run's imitation, in ``directory`` (module docstring)."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)

    @classmethod
    def of_run(cls, run_dir: str | Path) -> RoundStore:
        """The store of the run in ``run_dir`` (its `ROUNDS_DIR`)."""
        return cls(Path(run_dir) / ROUNDS_DIR)

    def save(self, progress: Progress, first_row: int, policy: Any, head: Any = None) -> None:
        """Round ``progress.rounds``: its rows (the batches from ``first_row`` on), then the
        policy's parameters (and ``head``'s) and the log."""
        import torch

        self.directory.mkdir(parents=True, exist_ok=True)
        arrays = {"labels": np.concatenate(progress.labels[first_row:])}
        batches = progress.observations[first_row:]
        if isinstance(batches[0], dict):
            for key in batches[0]:
                arrays[f"obs/{key}"] = np.concatenate([b[key] for b in batches])
        else:
            arrays["obs"] = np.concatenate(batches)
        if progress.views:
            arrays["views"] = np.concatenate(progress.views[first_row:])
        if progress.points:
            arrays["points"] = np.concatenate(progress.points[first_row:])
        rows = self.directory / f"round_{progress.rounds}.npz"
        atomic_write(rows, writer=lambda tmp: _save_npz(tmp, arrays))
        state = {
            "policy": policy.state_dict(),
            "head": None if head is None else head.state_dict(),
            "log": progress.log(),
        }
        atomic_write(self.directory / _STATE, writer=lambda tmp: torch.save(state, tmp))
        atomic_write(self.directory / _COUNT, json.dumps({"rounds": progress.rounds}).encode())

    def load(self, policy: Any) -> tuple[Progress, dict[str, Any] | None]:
        """The progress stored (an empty one where nothing is), the policy's parameters set to
        those after its last round; and the state regression head's parameters, if any."""
        path = self.directory / _STATE
        if not path.is_file():
            return Progress(), None
        try:
            return self._load(path, policy)
        except (OSError, EOFError, ValueError, KeyError, RuntimeError, pickle.UnpicklingError,
                zipfile.BadZipFile) as exc:  # fmt: skip
            raise CheckpointError(
                f"{self.directory}: the imitation's kept rounds cannot be read ({exc}); remove "
                "that folder to start the imitation again"
            ) from exc

    def _load(self, path: Path, policy: Any) -> tuple[Progress, dict[str, Any] | None]:
        import torch

        state = torch.load(path, map_location="cpu", weights_only=True)
        log = state["log"]
        progress = Progress(
            rounds=int(log["rounds"]),
            losses=list(log["losses"]),
            state_losses=list(log["state_losses"]),
            keypoint_px=list(log.get("keypoint_px", [])),
            agreement=list(log["agreement"]),
            curve=list(log["curve"]),
            elapsed_s=float(log["elapsed_s"]),
        )
        for r in range(1, progress.rounds + 1):
            with np.load(self.directory / f"round_{r}.npz") as data:
                arrays = {key: data[key] for key in data.files}
            progress.labels.append(arrays["labels"])
            obs_keys = [k for k in arrays if k.startswith("obs/")]
            if obs_keys:
                progress.observations.append({k[4:]: arrays[k] for k in obs_keys})
            else:
                progress.observations.append(arrays["obs"])
            if "views" in arrays:
                progress.views.append(arrays["views"])
            if "points" in arrays:
                progress.points.append(arrays["points"])
        policy.load_state_dict(state["policy"])
        return progress, state["head"]

    def rounds_done(self) -> int:
        """How many complete rounds the store holds (0 where it holds none or cannot say)."""
        try:
            return int(json.loads((self.directory / _COUNT).read_text())["rounds"])
        except (OSError, ValueError, KeyError, TypeError):
            return 0

    def clear(self) -> None:
        """Remove the store (a checkpoint holds the imitated policy)."""
        shutil.rmtree(self.directory, ignore_errors=True)


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    with open(path, "wb") as handle:  # a file object: np.savez adds no ".npz" to its name
        np.savez(handle, **arrays)
