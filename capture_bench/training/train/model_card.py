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
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import statistics
import sys
from pathlib import Path
from typing import Any

from capture_bench.files import atomic_write
from capture_bench.paths import models_dir
from capture_bench.task.scenarios import ConfigError, load_scenario
from capture_bench.training.common.policy_export import BEST_DIR, IMITATION_FILE, VALIDATION_FILE

#: The fields every model card has (``metadata.json`` key ``model_card``).
CARD_FIELDS = ("command", "total_timesteps", "wall_time_s", "hardware", "training_seed",
               "scenarios", "actions", "validation", "policy")  # fmt: skip
COPIED = ("policy.pt", "metadata.json", "model.zip")


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


def validate_policy(model_dir: Path, scenario: str, seeds: list[int]) -> dict[str, Any]:
    """The policy in ``model_dir`` on ``seeds`` of ``scenario``, as train.py validates: one
    deterministic episode per seed in the batched env, `CARD_BATCH` seeds at a time;
    per episode and summarised."""
    from capture_bench.agents.sb3_policy import load_policy, observation_options, read_metadata
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.training.common.episode_stats import summarize
    from capture_bench.training.common.validation_run import run_validation

    metadata = read_metadata(model_dir)
    loaded = load_policy(metadata)
    options = observation_options(metadata.image_size)  # pixels: pixel envs
    played = []
    for start in range(0, len(seeds), CARD_BATCH):
        batch = seeds[start : start + CARD_BATCH]
        env = CaptureVectorEnv(len(batch), scenario, **options)
        try:
            played += run_validation(loaded.agent("card", env.description), env, batch)
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
        **{k: summary[k] for k in ("capture_rate", "median_ratio_to_limit", "median_capture_time")},
    }


def ship(run_dir: Path, name: str, episodes: int, out: Path | None = None) -> Path:
    """Copy the run to ``models/<name>/`` with its model card; return the directory."""
    from capture_bench.provenance import machine
    from capture_bench.training.common.mixture import mixture_scenarios

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
    config = json.loads(config_file.read_text())["config"]
    target = (out or models_dir()) / name
    if target.exists():
        raise ConfigError(f"{target}: already exists; remove it or choose another --name")
    tmp = target.with_name(f".tmp-{name}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for file in COPIED:
        if (run_dir / file).is_file():
            shutil.copy2(run_dir / file, tmp / file)
    scenarios = [s.name for s in mixture_scenarios(config["scenario"])]
    validation = {}
    for scenario in scenarios:
        seeds = list(load_scenario(scenario).validation_seeds[:episodes])
        validation[scenario] = validate_policy(tmp, scenario, seeds)
    card = {
        "command": meta.get("command"),
        "total_timesteps": meta.get("total_timesteps"),
        "wall_time_s": meta.get("wall_time_s"),
        "hardware": machine(),
        "training_seed": meta.get("seed"),
        "scenarios": scenarios,
        "actions": meta.get("actions", "deterministic"),
        "validation": validation,
        # which of the run's policies: its last, or its best periodic validation (step, seeds)
        "policy": (
            {"kind": "best validation", "step": best["step"], "seeds": len(best["seeds"])}
            if best
            else {"kind": "final"}
        ),
    }
    imitation_file = config_file.parent / IMITATION_FILE
    if imitation_file.is_file():  # DAgger before the algorithm (training/imitation.py)
        from capture_bench.training.common.imitation import describe_teacher

        card["imitation"] = {
            "teacher": describe_teacher(meta.get("hyperparameters", {}).get("imitate", "")),
            **json.loads(imitation_file.read_text()),
        }
    meta["model_card"] = card
    atomic_write(tmp / "metadata.json", json.dumps(meta, indent=2).encode())
    atomic_write(tmp / "README.md", _readme(name, meta, card).encode())
    tmp.rename(target)
    return target


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
    steps = card["total_timesteps"] + (imitation["environment_steps"] if imitation else 0)
    imitated = []
    if imitation:
        warm = hp.get("imitation_warmup", 0)
        imitated = [
            f"- imitation: DAgger from `{imitation['teacher']}`, {imitation['rounds']} rounds, "
            f"{imitation['environment_steps']:,} environment steps on training seeds, "
            f"{hp.get('imitation_epochs')} passes of the fit after each (last fit MSE "
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
        + " The leaderboard's figures on the published evaluation seeds are in "
        "`reports/published/default`.",
        "",
    ])  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m capture_bench.training.train.model_card",
                                     description=__doc__.splitlines()[0])  # fmt: skip
    parser.add_argument(
        "run_dir", help="a finished run (or its best/); with --revalidate, models/<name>"
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
        model = Path(args.run_dir)
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
        target = ship(Path(args.run_dir), args.name, args.episodes)
    except ConfigError as exc:
        print(f"model_card: error: {exc}", file=sys.stderr)
        return 2
    print(f"shipped {target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
