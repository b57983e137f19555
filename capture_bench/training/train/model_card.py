"""Ship a trained policy: ``python -m capture_bench.training.train.model_card RUN_DIR --name NAME``.

RUN_DIR is a finished run (its final policy) or a run's ``best/`` (the policy of its best periodic
validation, as the RL Zoo ships ``best_model``; the card says which, and at which step). Copies
the safe policy (``policy.pt`` + ``metadata.json``, and SB3's ``model.zip``
for SB3 users) to ``models/NAME/``, plays its validation episodes (the first ``--episodes``
validation seeds of each scenario it was trained on, deterministic actions; never a published
evaluation seed) and writes the model card: the ``model_card`` entry of ``metadata.json`` and a
``README.md`` saying how it was trained (the command, steps, wall-clock, hardware, training seed)
and what it achieved on validation, episode by episode, so that ``tests/test_model_cards.py``
can replay a few episodes and check the card. ``evaluate.py`` then picks the model up in the
default leaderboard (``models/*``).

``python -m capture_bench.training.train.model_card RUN0 RUN1 RUN2 --name NAME`` ships runs that
differ only in their training seed as one model (`ship_seeds`): each seed's policy is validated
the same way and copied to ``models/NAME/seeds/<seed>/``, the seed of the median validation score
ships as above, and the card's ``seeds`` entry and the README's "Training seeds" section name the
seeds, the one shipped and each one's validation. Runs that differ in anything else, or repeat a
seed, are refused before anything is written.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import shutil
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from capture_bench.files import atomic_write
from capture_bench.paths import SEEDS_DIR, models_dir
from capture_bench.task.scenarios import ConfigError, load_scenario
from capture_bench.training.common.policy_export import BEST_DIR, IMITATION_FILE, VALIDATION_FILE

#: The fields every model card has (``metadata.json`` key ``model_card``).
CARD_FIELDS = ("command", "total_timesteps", "wall_time_s", "hardware", "training_seed",
               "scenarios", "actions", "validation", "policy")  # fmt: skip
COPIED = ("policy.pt", "metadata.json", "model.zip")
#: What `ship_seeds` copies of each training seed's run, to ``seeds/<seed>/``.
SEED_COPIED = ("policy.pt", "metadata.json")
#: How `ship_seeds` chooses the seed that ships.
SELECTION = "median validation score (validation seeds)"


#: Validation episodes are played in batches of this many seeds, in order. A policy's float32
#: forward pass rounds a row differently with the batch's size (torch picks its GEMM kernel by
#: shape: actions differ by ~1e-7), and over an episode that can move a capture by a
#: millisecond, so an episode replays exactly only in the same batch: the test replays the
#: card's first batch.
CARD_BATCH = 4

#: How a card's validation replays on a CPU other than the reference's: the replayed capture
#: count within this many standard deviations of the difference of two binomial draws (99%), and
#: the median relative change of the capture time, over the episodes captured in both, within
#: `REPLAY_TIME_TOLERANCE`.
REPLAY_Z = 2.576
REPLAY_TIME_TOLERANCE = 0.05
#: What a card's README says of its replay (tests/test_model_cards.py holds the card to it).
REPLAY_CHECK = (
    "`tests/test_model_cards.py` replays some of them: bit for bit (each episode's outcome and "
    "capture time) on the kind of machine that made the test suite's reference "
    "(`tests/data/default_suite_reference.json`); on another CPU, where the floats differ in "
    "their last bits and an episode on a knife edge can end the other way, the replayed capture "
    f"count must lie within {REPLAY_Z} standard deviations (99%) of the card's and the median "
    f"change of capture time within {REPLAY_TIME_TOLERANCE:.0%} (`replay_agrees`)."
)


def replay_agrees(recorded: list[dict[str, Any]], replayed: list[dict[str, Any]]) -> list[str]:
    """Where a replay of a card's episodes disagrees with the card beyond what another CPU's
    rounding explains (`REPLAY_CHECK`); empty when it agrees.

    ``recorded`` and ``replayed``: the same seeds in the same order, each ``{"seed",
    "captured", "capture_time"}`` as `validate_policy` writes them. The capture counts
    ``k1``, ``k2`` of ``n`` episodes may differ by ``1 + z * sqrt(2 n p (1 - p))`` with ``p``
    their pooled rate: two binomial draws of one policy whose knife-edge episodes fall either way.
    """
    if [e["seed"] for e in recorded] != [e["seed"] for e in replayed]:
        return ["the replay played other seeds than the card's"]
    n = len(recorded)
    k1 = sum(bool(e["captured"]) for e in recorded)
    k2 = sum(bool(e["captured"]) for e in replayed)
    problems = []
    pooled = (k1 + k2) / (2 * n) if n else 0.0
    allowed = 1 + REPLAY_Z * math.sqrt(2 * n * pooled * (1 - pooled))
    if abs(k1 - k2) > allowed:
        problems.append(
            f"captured {k2} of {n} on replay, the card {k1}: more than the {allowed:.1f} "
            "episodes another CPU's rounding explains"
        )
    changes = [
        abs(b["capture_time"] - a["capture_time"]) / a["capture_time"]
        for a, b in zip(recorded, replayed)
        if a["captured"] and b["captured"] and a["capture_time"]
    ]
    if changes and statistics.median(changes) > REPLAY_TIME_TOLERANCE:
        problems.append(
            f"capture times moved by a median {statistics.median(changes):.1%} on replay, more "
            f"than {REPLAY_TIME_TOLERANCE:.0%}"
        )
    return problems


#: What `validate_policy` keeps of the summary of a scenario's episodes.
VALIDATION_SUMMARY = ("capture_rate", "median_ratio_to_limit", "median_capture_time", "mean_score")


def validate_policy(model_dir: Path, scenario: str, seeds: list[int]) -> dict[str, Any]:
    """The policy in ``model_dir`` on ``seeds`` of ``scenario``, as train.py validates: one
    deterministic episode per seed in the batched env, `CARD_BATCH` seeds at a time;
    per episode and summarised."""
    from capture_bench.agents.sb3_policy import load_policy, read_metadata
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.training.common.episode_stats import summarize
    from capture_bench.training.common.validation_run import run_validation

    metadata = read_metadata(model_dir)
    loaded = load_policy(metadata)
    options = metadata.env_options  # pixels: pixel envs, with the model's pixel options
    played = []
    for start in range(0, len(seeds), CARD_BATCH):
        batch = seeds[start : start + CARD_BATCH]
        env = CaptureVectorEnv(len(batch), scenario, **options)
        try:
            played += run_validation(loaded.agent("card", env.description, env), env, batch)
        finally:
            env.close()
    summary = summarize(played)
    return {
        "seeds": seeds,
        "episodes": [
            {
                "seed": seed,
                "captured": bool(e.captured),
                "capture_time": e.capture_time if e.captured else None,
            }
            for seed, e in zip(seeds, played)
        ],  # fmt: skip
        **{k: summary[k] for k in VALIDATION_SUMMARY},
    }


@dataclass(frozen=True)
class Run:
    """A finished run (or its ``best/``) as shipping reads it.

    Attributes:
        directory: the policy's directory (the run's, or its ``best/``).
        meta: its ``metadata.json``.
        config: the run's ``config.json`` (``config``, ``hyperparameters``, ...).
        config_file: where ``config`` was read.
        best: `_best_validation` of ``best/`` (its step and seeds), None for the final policy.
    """

    directory: Path
    meta: dict[str, Any]
    config: dict[str, Any]
    config_file: Path
    best: dict[str, Any] | None

    @property
    def seed(self) -> int:
        """The training seed."""
        return int(self.meta.get("seed", self.config["config"].get("seed")))


def read_run(run_dir: Path) -> Run:
    """The run in ``run_dir`` (a finished run or its ``best/``); `ConfigError` if it is none."""
    run_dir = Path(run_dir)
    meta_file = run_dir / "metadata.json"
    if not meta_file.is_file() or not (run_dir / "policy.pt").is_file():
        raise ConfigError(
            f"{run_dir}: not a finished run or its {BEST_DIR}/ (no policy.pt + metadata.json)"
        )
    meta = json.loads(meta_file.read_text())
    best = _best_validation(run_dir)  # RUN/best: the run's best periodic validation
    config_file = (run_dir.parent if best else run_dir) / "config.json"
    if not config_file.is_file():
        raise ConfigError(f"{config_file}: missing; ship a run directory or its {BEST_DIR}/")
    config = json.loads(config_file.read_text())
    return Run(run_dir, meta, config, config_file, best)


def ship(run_dir: Path, name: str, episodes: int, out: Path | None = None) -> Path:
    """Copy the run to ``models/<name>/`` with its model card; return the directory."""
    run = read_run(run_dir)
    target, tmp = _staging(name, out)
    _copy(run.directory, tmp, COPIED)
    validation = _validate(tmp, _scenarios(run), episodes)
    _finish(tmp, target, name, run.meta, _card(run, validation))
    return target


def ship_seeds(run_dirs: list[Path], name: str, episodes: int, out: Path | None = None) -> Path:
    """Ship runs that differ only in their training seed as one model: each run's policy is
    validated (`validate_policy`, on validation seeds only) and copied to ``seeds/<seed>/``,
    and the run of the median validation score (`median_seed`) ships as `ship` ships one run,
    its card naming every seed (``model_card["seeds"]``); return the directory.

    Raises:
        ConfigError: a directory that is no run, runs that differ in more than the seed
            (`seed_difference`), or a seed given twice; nothing is written.
    """
    runs = [read_run(d) for d in run_dirs]
    problem = seed_difference(runs)
    if problem:
        raise ConfigError(problem)
    target, tmp = _staging(name, out)
    try:
        _ship_seeds(runs, tmp, target, name, episodes)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


def _ship_seeds(runs: list[Run], tmp: Path, target: Path, name: str, episodes: int) -> None:
    scenarios = _scenarios(runs[0])
    validations = {}
    for run in runs:
        copy = tmp / SEEDS_DIR / str(run.seed)
        copy.mkdir(parents=True)
        _copy(run.directory, copy, SEED_COPIED)
        validations[run.seed] = _validate(copy, scenarios, episodes)
    scores = {seed: validation_score(v) for seed, v in validations.items()}
    shipped = median_seed(scores)
    run = next(r for r in runs if r.seed == shipped)
    _copy(run.directory, tmp, COPIED)
    card = _card(run, validations[shipped])
    card["seeds"] = {
        "trained": sorted(scores),
        "shipped": shipped,
        "selection": SELECTION,
        "scores": {str(seed): scores[seed] for seed in sorted(scores)},
        "validation": {
            str(seed): {scenario: _summary(v) for scenario, v in validations[seed].items()}
            for seed in sorted(validations)
        },
    }
    _finish(tmp, target, name, run.meta, card)


def validation_score(validation: dict[str, dict[str, Any]]) -> float:
    """The mean per-episode score (`capture_bench.task.score.episode_score`) over every
    validation episode of every scenario of a `_validate` result."""
    total = sum(v["mean_score"] * len(v["episodes"]) for v in validation.values())
    return total / sum(len(v["episodes"]) for v in validation.values())


def median_seed(scores: dict[int, float]) -> int:
    """The seed whose score is the median of ``scores`` ({seed: score}; the lower middle one
    of an even count), the lowest such seed where several have it."""
    values = sorted(scores.values())
    middle = values[(len(values) - 1) // 2]
    return min(seed for seed, value in scores.items() if value == middle)


def seed_difference(runs: list[Run]) -> str | None:
    """Why ``runs`` cannot ship as the training seeds of one model (one line), None if they
    can: fewer than two, a seed given twice, or a setting other than the seed that differs
    (`_settings`: the first one, with each run's value)."""
    if len(runs) < 2:
        return "several training seeds need at least two runs"
    seeds = [run.seed for run in runs]
    repeated = sorted({s for s in seeds if seeds.count(s) > 1})
    if repeated:
        where = ", ".join(str(r.directory) for r in runs if r.seed in repeated)
        return f"runs repeat training seed {repeated[0]} ({where}); each seed ships once"
    settings = [_settings(run) for run in runs]
    keys = list(dict.fromkeys(k for s in settings for k in s))
    differ = [k for k in keys if any(s.get(k) != settings[0].get(k) for s in settings)]
    if not differ:
        return None
    first = differ[0]
    values = ", ".join(f"{s.get(first)!r} in {r.directory}" for s, r in zip(settings, runs))
    more = f" (and {len(differ) - 1} more)" if len(differ) > 1 else ""
    return f"runs differ in more than the seed: {first}: {values}{more}"


def _settings(run: Run) -> dict[str, Any]:
    """What must be the same in every seed of a model, flat: the run's configuration but its
    seed and folder, its hyper-parameters, the metadata naming its algorithm, scenario,
    observation source, reward and residual, its command but ``--seed``/``--run-dir``, and
    which policy of the run (final or best validation)."""
    config = {k: v for k, v in run.config["config"].items() if k not in ("seed", "run_dir")}
    flat = _flat("hyper-parameter ", run.config.get("hyperparameters", {}))
    flat |= {f"{k}": run.meta.get(k) for k in SAME_METADATA}
    flat |= _flat("config ", config)
    flat["command"] = _command_but_seed(run.meta.get("command") or "")
    flat["policy"] = "best validation" if run.best else "final"
    return flat


#: Metadata fields every seed of a model shares.
SAME_METADATA = ("algorithm", "scenario", "observation_source", "reward", "residual")
#: Command-line options of train.py that may differ between the seeds of a model.
SEED_OPTIONS = ("--seed", "--run-dir")


def _flat(prefix: str, value: Any) -> dict[str, Any]:
    """``value`` flat: each leaf under its dotted path after ``prefix``."""
    if not isinstance(value, dict):
        return {prefix.rstrip("."): value}
    out: dict[str, Any] = {}
    for key, item in value.items():
        out |= _flat(f"{prefix}{key}.", item)
    return out


def _command_but_seed(command: str) -> str:
    words, kept = shlex.split(command), []
    skip = False
    for word in words:
        if skip:
            skip = False
        elif word in SEED_OPTIONS:
            skip = True
        elif not word.startswith(tuple(f"{o}=" for o in SEED_OPTIONS)):
            kept.append(word)
    return shlex.join(kept)


def _staging(name: str, out: Path | None) -> tuple[Path, Path]:
    """``(models/<name>, its empty temporary sibling)``; `ConfigError` if the model exists."""
    target = (out or models_dir()) / name
    if target.exists():
        raise ConfigError(f"{target}: already exists; remove it or choose another --name")
    tmp = target.with_name(f".tmp-{name}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    return target, tmp


def _copy(source: Path, dest: Path, files: tuple[str, ...]) -> None:
    for file in files:
        if (source / file).is_file():
            shutil.copy2(source / file, dest / file)


def _scenarios(run: Run) -> list[str]:
    from capture_bench.training.common.mixture import mixture_scenarios

    return [s.name for s in mixture_scenarios(run.config["config"]["scenario"])]


def _validate(model_dir: Path, scenarios: list[str], episodes: int) -> dict[str, Any]:
    """`validate_policy` on the first ``episodes`` validation seeds of each scenario."""
    return {
        scenario: validate_policy(
            model_dir, scenario, list(load_scenario(scenario).validation_seeds[:episodes])
        )
        for scenario in scenarios
    }


def _summary(validation: dict[str, Any]) -> dict[str, Any]:
    """A scenario's validation without its episodes."""
    return {k: v for k, v in validation.items() if k != "episodes"}


def _card(run: Run, validation: dict[str, Any]) -> dict[str, Any]:
    from capture_bench.provenance import machine

    meta, best = run.meta, run.best
    card = {
        "command": meta.get("command"),
        "total_timesteps": meta.get("total_timesteps"),
        "wall_time_s": meta.get("wall_time_s"),
        "hardware": machine(),
        "training_seed": meta.get("seed"),
        "scenarios": list(validation),
        "actions": meta.get("actions", "deterministic"),
        "validation": validation,
        # which of the run's policies: its last, or its best periodic validation (step, seeds)
        "policy": (
            {"kind": "best validation", "step": best["step"], "seeds": len(best["seeds"])}
            if best
            else {"kind": "final"}
        ),
    }
    imitation_file = run.config_file.parent / IMITATION_FILE
    if imitation_file.is_file():  # DAgger before the algorithm (training/imitation.py)
        from capture_bench.training.common.imitation import describe_teacher

        card["imitation"] = {
            "teacher": describe_teacher(meta.get("hyperparameters", {}).get("imitate", "")),
            **json.loads(imitation_file.read_text()),
        }
    return card


def _finish(tmp: Path, target: Path, name: str, meta: dict[str, Any], card: dict[str, Any]):
    """Write the card into ``tmp`` (``metadata.json``, ``README.md``) and rename it ``target``."""
    meta = {**meta, "model_card": card}
    atomic_write(tmp / "metadata.json", json.dumps(meta, indent=2).encode())
    atomic_write(tmp / "README.md", _readme(name, meta, card).encode())
    tmp.rename(target)


#: The README section that `revalidate` writes (and rewrites).
ENVELOPE_SECTION = "## Under the capture envelope (v1 environments)"
#: The README section of a card's validation, as shipped; `revalidate` renames it
#: (`VALIDATION_V0_HEADING`) when the card's ``validation`` becomes the current rule's.
VALIDATION_HEADING = (
    "## Validation (deterministic actions, validation seeds, never a published one)"
)
VALIDATION_V0_HEADING = (
    "## Validation when shipped, under the v0 rule (deterministic actions, validation seeds)"
)


def revalidate(model_dir: Path) -> dict[str, Any]:
    """Replay a shipped model's validation seeds under the scenarios' current capture rule and
    make that its card's ``validation`` (what ``tests/test_model_cards.py`` replays), keeping the
    results it was trained and selected under as ``validation_v0``; the README gains a section
    with both. Returns the new ``validation``. The model's files are not touched otherwise."""
    meta_file = model_dir / "metadata.json"
    meta = json.loads(meta_file.read_text())
    card = meta["model_card"]
    before = card.get("validation_v0", card["validation"])
    after = {
        scenario: validate_policy(model_dir, scenario, list(recorded["seeds"]))
        for scenario, recorded in before.items()
    }
    card["validation_v0"], card["validation"] = before, after
    atomic_write(meta_file, json.dumps(meta, indent=2).encode())
    readme = model_dir / "README.md"
    text = readme.read_text()
    if ENVELOPE_SECTION in text:  # rewritten: everything from the section to the next one
        head, _, rest = text.partition(ENVELOPE_SECTION)
        tail = rest[rest.find("\n## ") + 1 :] if "\n## " in rest else ""
        text = head + tail
    section = _envelope_section(before, after)
    text = text.replace(VALIDATION_HEADING, VALIDATION_V0_HEADING).replace(
        "(`model_card.validation`)", "(`model_card.validation_v0`)"
    )
    marker = "\n## Validation"
    at = text.find(marker)
    text = text + "\n" + section if at < 0 else text[: at + 1] + section + text[at + 1 :]
    atomic_write(readme, text.encode())
    return after


def _ratio(value: float) -> str:
    return "-" if value != value else f"{value:.2f}"


def _envelope_section(before: dict[str, Any], after: dict[str, Any]) -> str:
    """The README section of `revalidate`: each scenario's validation under the capture
    envelope beside the rule it was trained under."""
    rows = [
        f"| {scenario} | {after[scenario]['capture_rate']:.2f} | "
        f"{_ratio(after[scenario]['median_ratio_to_limit'])} | {v['capture_rate']:.2f} | "
        f"{_ratio(v['median_ratio_to_limit'])} | {len(v['seeds'])} |"
        for scenario, v in before.items()
    ]
    return "\n".join([
        ENVELOPE_SECTION,
        "",
        "This policy was trained and selected under the paper's eq. 20 alone (the v0 rule: any "
        "speed, and on most scenarios 1 mm at one instant). The same validation seeds played "
        "under the capture envelope, as the leaderboard now judges it (docs/capture_envelope.md),"
        " beside the v0 results it shipped with (`model_card.validation_v0`):",
        "",
        "| scenario | capture rate, envelope | median ratio, envelope | capture rate, v0 | "
        "median ratio, v0 | seeds |",
        "|---|---|---|---|---|---|",
        *rows,
        "",
        "",
    ])  # fmt: skip


def _best_validation(directory: Path) -> dict[str, Any] | None:
    """`VALIDATION_FILE` of a run's ``best/`` directory (its step and seeds), as
    `BestModel` writes it; None for a run
    directory."""
    found = directory / VALIDATION_FILE
    if directory.name != BEST_DIR or not found.is_file():
        return None
    try:
        data = json.loads(found.read_text())
        return {"step": int(data["step"]), "seeds": list(data["seeds"])}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{found}: unreadable ({exc}); it is written by train.py") from None


def _readme(name: str, meta: dict[str, Any], card: dict[str, Any]) -> str:
    hp = meta.get("hyperparameters", {})
    hardware = card["hardware"]
    rows = [
        f"| {scenario} | {v['capture_rate']:.2f} | "
        + ("-" if v["median_ratio_to_limit"] != v["median_ratio_to_limit"]
           else f"{v['median_ratio_to_limit']:.2f}")
        + f" | {len(v['seeds'])} ({v['seeds'][0]}-{v['seeds'][-1]}) |"
        for scenario, v in card["validation"].items()
    ]  # fmt: skip
    residual = meta.get("residual")
    imitation = card.get("imitation")
    kind = (
        f"a hybrid: a residual on `{residual['base']}` scaled by {residual['scale']}"
        if residual
        else "a learned controller on its own"
        + (f", started by imitating `{imitation['teacher']}`" if imitation else "")
    )
    front_end = meta.get("front_end")
    if meta.get("observation_source") == "pixels":
        kind += (
            "; from the camera's pixels, no estimator"
            + (f", through the `{front_end['name']}` front end" if front_end else "")
            + " ([docs/pixels.md](../../docs/pixels.md))"
        )
        published = (
            "Its figures on the published evaluation seeds come from `python evaluate.py --suite "
            "pixels` (a policy that sees pixels is not in the default suite's `models/*`)."
        )
    else:
        published = (
            "The leaderboard's figures on the published evaluation seeds are in "
            "`reports/published/default`."
        )
    steps = card["total_timesteps"] + (imitation["environment_steps"] if imitation else 0)
    imitated = []
    if imitation:
        warm = hp.get("imitation_warmup", 0)
        fit_steps = (  # a config without the keys took the defaults, which the card leaves unnamed
            f"Adam at {hp['imitation_lr']:g}, minibatches of {hp['imitation_batch']}; "
            if "imitation_lr" in hp
            else ""
        )
        if hp.get("imitation_state_weight"):
            fit_steps += (
                f"plus {hp['imitation_state_weight']:g} x the error of a regression of the "
                "teacher's observation from the policy's features; "
            )
        if hp.get("imitation_keypoint_weight"):
            fit_steps += (
                f"plus {hp['imitation_keypoint_weight']:g} x the keypoints' loss against the "
                "markers' true image points; "
            )
        imitated = [
            f"- imitation: DAgger from `{imitation['teacher']}`, {imitation['rounds']} rounds, "
            f"{imitation['environment_steps']:,} environment steps on training seeds, "
            f"{hp.get('imitation_epochs')} passes of the fit after each ({fit_steps}last fit MSE "
            f"{imitation['fit_mse'][-1]:.1e}), {imitation['wall_time_s']:.0f} s; then "
            f"{card['total_timesteps']:,} steps of {meta.get('algorithm')}, the actor frozen "
            f"for the first {min(warm, card['total_timesteps']):,}"
            + (" (the critic alone learned: the policy is the imitation's)"
               if warm >= card["total_timesteps"] else "")
        ]  # fmt: skip
    return "\n".join([
        f"# {name}",
        "",
        f"{meta.get('algorithm')} trained by `train.py` on "
        f"{', '.join(f'`{s}`' for s in card['scenarios'])} ({kind}); "
        f"{card['actions']} actions on the leaderboard.",
        "",
        "## How it was trained",
        "",
        f"- command: `{card['command']}`",
        f"- environment steps: {steps:,}"
        + (f" ({card['total_timesteps']:,} of them the algorithm's)" if imitation else ""),
        *imitated,
        *(
            [f"- policy: the run's best periodic validation (`best/`), at step "
             f"{card['policy']['step']:,}, on {card['policy']['seeds']} validation seeds"]
            if card["policy"]["kind"] != "final" else []
        ),  # fmt: skip
        f"- training wall-clock: {card['wall_time_s']:.0f} s "
        f"({steps / max(card['wall_time_s'], 1e-9):.1f} steps/s, validations included)",
        f"- hardware: {hardware['cpu']}, {hardware['cores']} cores ({hardware['system']}); "
        f"torch on {meta.get('device')}",
        f"- training seed: {card['training_seed']} (training seeds only)",
        f"- git: {meta.get('git')}",
        f"- hyper-parameters: reward {hp.get('reward')}, n_envs {hp.get('n_envs')}, "
        f"policy_kwargs {hp.get('policy_kwargs')}",
        "",
        VALIDATION_HEADING,
        "",
        "| scenario | capture rate | median ratio to the physical limit | seeds |",
        "|---|---|---|---|",
        *rows,
        "",
        "Each episode is in `metadata.json` (`model_card.validation`); " + REPLAY_CHECK
        + " " + published,
        "",
        *(_seeds_section(card["seeds"]) if "seeds" in card else []),
    ])  # fmt: skip


#: The README section of a model shipped from several training seeds (`ship_seeds`).
SEEDS_HEADING = "## Training seeds"


def _seeds_section(seeds: dict[str, Any]) -> list[str]:
    """The README's section on a model's training seeds: which ones, which ships and why, and
    each one's validation."""
    trained = ", ".join(map(str, seeds["trained"]))
    rows = [
        f"| {seed}{' (shipped)' if seed == seeds['shipped'] else ''} | "
        f"{seeds['scores'][str(seed)]:.3f} | {scenario} | {v['capture_rate']:.2f} | "
        f"{_ratio(v['median_ratio_to_limit'])} |"
        for seed in seeds["trained"]
        for scenario, v in seeds["validation"][str(seed)].items()
    ]
    return [
        SEEDS_HEADING,
        "",
        f"Trained with {len(seeds['trained'])} seeds, {trained}, by the same command but for "
        f"`--seed` and `--run-dir`. The policy shipped is seed {seeds['shipped']}'s: the "
        "median of the seeds' validation scores (the mean per-episode score over the validation "
        "seeds above, physical limit / capture time for a capture and 0 for a failure; the "
        "lower seed where two have the median), so nothing is chosen on a published seed. Each "
        "seed's policy is in `seeds/<seed>/`; the leaderboard plays every one on its episodes "
        "and reports their IQM with its interval beside the shipped policy's row.",
        "",
        "| seed | validation score | scenario | capture rate | median ratio to the physical "
        "limit |",
        "|---|---|---|---|---|",
        *rows,
        "",
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m capture_bench.training.train.model_card",
                                     description=__doc__.splitlines()[0])  # fmt: skip
    parser.add_argument(
        "run_dir",
        nargs="+",
        help="a finished run (or its best/); several: the same run with other training seeds, "
        "shipped as one model (ship_seeds); with --revalidate, models/<name>",
    )
    parser.add_argument("--name", help="models/<name>/ (required unless --revalidate)")
    parser.add_argument(
        "--revalidate",
        action="store_true",
        help="replay a shipped model's validation seeds under the current capture rule and "
        "update its card (revalidate)",
    )
    parser.add_argument("--episodes", type=int, default=20, help="validation seeds per scenario")
    args = parser.parse_args(argv)
    if args.revalidate:
        if len(args.run_dir) != 1:
            print("model_card: error: --revalidate takes one model directory", file=sys.stderr)
            return 2
        model = Path(args.run_dir[0])
        if not (model / "metadata.json").is_file():
            print(
                f"model_card: error: {model}: no metadata.json (a shipped model)", file=sys.stderr
            )
            return 2
        for scenario, v in revalidate(model).items():
            print(f"{model.name} {scenario}: capture rate {v['capture_rate']:.2f} (envelope)")
        return 0
    if not args.name:
        print("model_card: error: --name is required to ship a run", file=sys.stderr)
        return 2
    try:
        runs = [Path(d) for d in args.run_dir]
        target = (
            ship(runs[0], args.name, args.episodes)
            if len(runs) == 1
            else ship_seeds(runs, args.name, args.episodes)
        )
    except ConfigError as exc:
        print(f"model_card: error: {exc}", file=sys.stderr)
        return 2
    print(f"shipped {target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
