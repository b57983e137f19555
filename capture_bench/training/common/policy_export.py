"""The trained policy as ``train.py`` writes it: the safe form (``policy.pt`` + ``metadata.json``,
`capture_bench.agents.policy_file`) with the run's provenance, at the end of a run and as
the run's best validated model so far, ``best/``.

``best/`` is what `BestModel` keeps: after a periodic validation whose result is better
(`is_better`: a higher validation capture rate, then a lower median ratio of capture time to
the physical limit, then a lower median capture time), the policy at that step is written as
``best/policy.pt`` + ``best/metadata.json`` (loadable by ``evaluate.py --agents RUN/best`` like the
final policy), SB3's ``best/model.zip`` (+ ``vecnormalize.pkl``) as at the end of a run, and
``best/validation.json`` (the step and the validation statistics). It is written
into a temporary directory that is then renamed onto ``best/``: a reader finds the previous best
whole or the new one whole, never a mix (for an instant between the two renames, none).
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from capture_bench.files import atomic_write
from capture_bench.task.scenarios import load_scenario
from capture_bench.training.config.options import command_line
from capture_bench.training.config.settings import TrainingSettings

BEST_DIR = "best"
VALIDATION_FILE = "validation.json"
WALL_TIME_FILE = "wall_time.json"
#: How `is_better` ranks validations, as written into ``validation.json``.
SELECTION_RULE = (
    "highest capture_rate, then lowest median_ratio_to_limit, then lowest median_capture_time "
    "(NaN ranks last)"
)


#: Every validation of a run, one row each: ``step``, ``wall_time_s`` (training time of the run
#: so far, validations included), then the statistics. Read by
#: `capture_bench.training.curves.command`.
VALIDATIONS_FILE = "validations.csv"
#: What a run's imitation did (`capture_bench.training.common.imitation.dagger`), as JSON.
IMITATION_FILE = "imitation.json"


def append_validation(
    run_dir: Path, step: int, wall_time_s: float, stats: dict[str, float]
) -> None:
    """Append one validation's row to ``run_dir/validations.csv`` (header on first write).

    A file whose header lacks some of ``stats`` is first rewritten with those columns added at
    the end, empty in its earlier rows, so every row stays under its header; a column of the file
    that ``stats`` lacks is left empty."""
    import csv
    import io

    path = Path(run_dir) / VALIDATIONS_FILE
    fields = ["step", "wall_time_s", *stats]
    if path.is_file():
        with open(path, newline="") as handle:
            reader = csv.DictReader(handle)
            header, rows = list(reader.fieldnames or []), list(reader)
        missing = [f for f in fields if f not in header]
        if missing:
            header += missing
            text = io.StringIO()
            writer = csv.DictWriter(text, header, restval="", lineterminator="\r\n")
            writer.writeheader()
            writer.writerows(rows)
            atomic_write(path, text.getvalue().encode())
        fields = header
    new = not path.is_file()
    with open(path, "a", newline="") as handle:
        writer = csv.DictWriter(handle, fields, restval="")
        if new:
            writer.writeheader()
        writer.writerow({"step": step, "wall_time_s": round(wall_time_s, 2), **stats})


def recorded_wall_time(run_dir: Path) -> float:
    """Training time of the run's finished sessions (``wall_time.json``), s; 0 if none."""
    path = Path(run_dir) / WALL_TIME_FILE
    return float(json.loads(path.read_text())["wall_time_s"]) if path.is_file() else 0.0


def policy_metadata(
    model: Any, config: Any, settings: TrainingSettings, wall_time_s: float, sb3_files: bool
) -> dict[str, Any]:
    """The provenance entries of ``metadata.json`` (the network's declaration is added by
    `capture_bench.agents.policy_file.save_policy`).

    Args:
        model: the SB3 algorithm.
        config: the run's `TrainConfig`.
        settings: its validated hyper-parameters.
        wall_time_s: training time so far over all sessions of the run, s.
        sb3_files: the directory also holds SB3's ``model.zip`` (+ ``vecnormalize.pkl`` where
            observations are normalised), named in ``model`` and ``vecnormalize``.
    """
    from capture_bench.provenance import git_state, package_versions
    from capture_bench.training.common.mixture import is_mixture, mixture_name

    mixed = is_mixture(config.scenario)
    scenario = None if mixed else load_scenario(config.scenario)
    normalized = model.get_vec_normalize_env() is not None
    steps = int(model.num_timesteps)
    front_end = settings.front_end_spec
    return {
        "algorithm": config.algo.upper(),
        "scenario": mixture_name(config.scenario) if scenario is None else scenario.name,
        "env_id": None if scenario is None else scenario.env_id,  # a mixture: one per scenario
        "model": "model.zip" if sb3_files else None,
        "observation_source": config.observation_source,
        "reward": settings.reward,
        "vecnormalize": "vecnormalize.pkl" if sb3_files and normalized else None,
        "total_timesteps": steps,
        "seed": config.seed,
        "n_envs": config.n_envs,
        "device": str(model.device),
        "wall_time_s": round(wall_time_s, 1),  # training time over all sessions of the run
        "steps_per_second": round(steps / wall_time_s, 1) if wall_time_s else None,
        **_code_state(config, git_state()),
        "packages": package_versions(),
        "hyperparameters": settings.to_mapping(),
        "command": command_line(config),
        "residual": None
        if settings.residual == "none"
        else {"base": settings.residual, "scale": settings.residual_scale},
        # the front end the policy network reads the pixels through (its steps, the image size)
        "front_end": None if front_end is None else front_end.metadata(),
        # the pixel observation's options (frame stack, end-effector crop, area sampling) that
        # evaluation makes the model's envs with; none: the original observation
        "pixel_observation": {
            key: value for key, value in settings.pixel_options.items() if key != "image_size"
        }
        or None,
    }


def _code_state(config: Any, now: dict[str, object]) -> dict[str, object]:
    """``{"git": the code the run started from}`` (its ``config.json``; runs started before it
    was recorded there: the code now), and ``"git_at_save"`` where the code now differs: a long
    run outlives commits made while it trains, and the policy is the starting code's."""
    saved = Path(config.run_dir) / "config.json" if config.run_dir else None
    start = json.loads(saved.read_text()).get("git") if saved and saved.is_file() else None
    if start is None or start == now:
        return {"git": now}
    return {"git": start, "git_at_save": now}


def export_policy(directory: Path, model: Any, metadata: dict[str, Any]) -> Path:
    """Write ``model``'s policy in the safe form into ``directory`` with ``metadata``'s entries;
    return the metadata file."""
    from capture_bench.agents.policy_file import ObservationNormalizer, save_policy
    from capture_bench.training.common.asymmetric import AsymmetricActorCriticPolicy, actor_policy

    env = model.get_vec_normalize_env()
    normalizer = None if env is None else ObservationNormalizer.from_vecnormalize(env)
    policy = model.policy
    if isinstance(policy, AsymmetricActorCriticPolicy):  # stored without the true state
        policy = actor_policy(policy)
    return save_policy(directory, metadata["algorithm"], policy, normalizer, extra=metadata)


def save_sb3_files(directory: Path, model: Any) -> None:
    """SB3's own ``model.zip`` (+ ``vecnormalize.pkl``) beside the safe policy, for SB3 users
    who trust the run (loading them unpickles)."""
    atomic_write(Path(directory) / "model.zip", writer=model.save)
    env = model.get_vec_normalize_env()
    if env is not None:
        atomic_write(Path(directory) / "vecnormalize.pkl", writer=env.save)


def _rank(stats: Mapping[str, float]) -> tuple[float, float, float]:
    """Sort key, smaller is better (NaN: worst)."""

    def low(key: str) -> float:
        value = float(stats.get(key, math.nan))
        return math.inf if math.isnan(value) else value

    rate = float(stats.get("capture_rate", math.nan))
    return (-rate if not math.isnan(rate) else math.inf, low("median_ratio_to_limit"),
            low("median_capture_time"))  # fmt: skip


def is_better(new: Mapping[str, float], old: Mapping[str, float] | None) -> bool:
    """Whether validation ``new`` beats ``old`` (None: nothing yet) by `SELECTION_RULE`;
    a tie is not better (the earlier model stays)."""
    return old is None or _rank(new) < _rank(old)


def _plain(stats: Mapping[str, float]) -> dict[str, float | None]:
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in stats.items()}


class BestModel:
    """Keeps ``run_dir/best/``: the policy of the best validation so far (module docstring).

    Args:
        run_dir: the run directory; an existing ``best/validation.json`` (a resumed run) is the
            result to beat.
    """

    def __init__(self, run_dir: Path) -> None:
        self.directory = Path(run_dir) / BEST_DIR
        self.stats: dict[str, float] | None = None
        path = self.directory / VALIDATION_FILE
        if path.is_file():
            try:
                saved = json.loads(path.read_text())["validation"]
                self.stats = {k: math.nan if v is None else float(v) for k, v in saved.items()}
            except (OSError, ValueError, KeyError, TypeError, AttributeError):
                self.stats = None  # unreadable: the next validation replaces it

    def offer(
        self,
        model: Any,
        stats: Mapping[str, float],
        seeds: Sequence[int],
        metadata: dict[str, Any],
    ) -> bool:
        """Write ``best/`` from ``model`` if ``stats`` (its validation on ``seeds``) beats the
        best so far; return whether it did."""
        if not is_better(stats, self.stats):
            return False
        parent, pid = self.directory.parent, os.getpid()
        tmp = parent / f".tmp-{pid}-{BEST_DIR}"
        old = parent / f".old-{pid}-{BEST_DIR}"
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)
        export_policy(tmp, model, metadata)
        save_sb3_files(tmp, model)  # model.zip, as the RL Zoo keeps best_model.zip
        record = {
            "step": int(model.num_timesteps),
            "seeds": [int(s) for s in seeds],
            "selection": SELECTION_RULE,
            "validation": _plain(stats),
        }
        text = json.dumps(record, indent=2, allow_nan=False) + "\n"
        atomic_write(tmp / VALIDATION_FILE, text.encode())
        if self.directory.exists():
            os.replace(self.directory, old)
        os.replace(tmp, self.directory)
        shutil.rmtree(old, ignore_errors=True)
        self.stats = dict(stats)
        return True
