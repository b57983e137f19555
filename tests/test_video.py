"""Episodes to watch (issue 15 point 3): ``evaluate.py --video DIR`` writes playable GIFs of the
tables' own episodes, the report embeds the reference and the best-ranked trained model on one
seed of each scenario, the suite's ``videos`` key switches it off, and gymnasium's
``RecordVideo`` works over the env with the ``video`` extra."""

from __future__ import annotations

import base64
import csv
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from PIL import Image
from test_evaluation_metrics import record

from capture_bench.evaluation.reporting.aggregate import RankingRow
from capture_bench.evaluation.reporting.report import csv_value
from capture_bench.evaluation.reporting.watch import choose_episodes
from capture_bench.evaluation.running.rollout import TIMING_COLUMNS
from capture_bench.evaluation.running.suites import SuiteError, load_suite
from capture_bench.evaluation.running.video import FRAME_SIZE
from capture_bench.task.scenarios import load_scenario
from evaluate import main

PAPER_SEEDS = load_scenario("paper").evaluation_seeds


def _table_row(report: Path, agent: str, seed: int) -> dict[str, str]:
    with open(report / "episodes.csv", newline="") as handle:
        rows = [r for r in csv.DictReader(handle) if (r["agent"], r["seed"]) == (agent, str(seed))]
    assert len(rows) == 1
    return {k: v for k, v in rows[0].items() if k not in TIMING_COLUMNS}


def _row(episode) -> dict[str, str]:
    """An EpisodeRecord as its episodes.csv row reads back (timing columns left out)."""
    return {k: str(csv_value(v)) for k, v in episode.as_row().items() if k not in TIMING_COLUMNS}


def test_video_writes_a_playable_gif_of_a_quick_episode(tmp_path):
    argv = ["--agents", "incremental_ik", "--scenarios", "paper", "--episodes", "1"]
    argv += ["--workers", "1", "--out", str(tmp_path / "reports")]
    assert main([*argv, "--video", str(tmp_path / "videos")]) == 0
    (gif,) = (tmp_path / "videos").iterdir()
    assert gif.name == f"incremental_ik_paper_seed{PAPER_SEEDS[0]}.gif"
    with Image.open(gif) as image:
        assert image.format == "GIF" and image.size == FRAME_SIZE
        assert image.n_frames > 1 and image.is_animated
        image.seek(image.n_frames - 1)  # every frame decodes
    (report,) = (tmp_path / "reports").iterdir()
    assert gif.read_bytes() == (report / gif.name).read_bytes()  # the report's own, reused


@pytest.fixture(scope="module")
def watched(tmp_path_factory, evaluated):
    """The reference, a shipped trained model and hold on paper, 3 seeds; the ReportData and the
    report folder."""
    argv = ["--agents", "incremental_ik,models/dagger-dls-paper,hold", "--scenarios", "paper"]
    return evaluated([*argv, "--episodes", "3", "--workers", "1"], tmp_path_factory.mktemp("w"))


def test_the_report_shows_the_reference_and_the_best_trained_model_on_one_seed(watched):
    data, folder = watched
    videos = data.videos
    assert [v.record.agent for v in videos] == ["incremental_ik", "dagger-dls-paper"]
    reference = [r for r in data.records if r.agent == "incremental_ik"]
    first_capture = next(r.seed for r in reference if r.captured)
    assert {v.record.seed for v in videos} == {first_capture}
    for video in videos:  # the same episode as the table's: outcome, failure, steps, times
        assert _row(video.record) == _table_row(folder, video.record.agent, video.record.seed)
    html = (folder / "leaderboard.html").read_text()
    md = (folder / "leaderboard.md").read_text()
    assert html.count("data:image/gif;base64,") == 2 and "<h2>Episodes to watch</h2>" in html
    for video in videos:
        written = (folder / video.file_name).read_bytes()
        assert written == video.gif and written.startswith(b"GIF89a")
        assert base64.b64encode(written).decode("ascii") in html
        assert f"({video.file_name})" in md and video.caption() in html
    assert "captured at" in videos[0].caption() and f"seed {first_capture}" in videos[0].caption()


def test_two_workers_record_the_same_videos_and_draw_the_same_figures(watched, evaluated, tmp_path):
    """With the process backend the GIFs and the figures are made in worker processes: the
    same bytes as one process makes (a fresh ``evaluate.py --workers 1``, as a user runs it: this
    test process has drawn other reports' figures before)."""
    import subprocess
    import sys

    data, _ = watched
    argv = ["--agents", "incremental_ik,models/dagger-dls-paper,hold", "--scenarios", "paper"]
    argv += ["--episodes", "3"]
    pooled, pooled_folder = evaluated([*argv, "--workers", "2"], tmp_path / "pooled")
    assert pooled.provenance["backend"] == {"name": "process", "workers": 2}
    assert [v.gif for v in pooled.videos] == [v.gif for v in data.videos]
    serial = tmp_path / "serial"
    done = subprocess.run(
        [sys.executable, "evaluate.py", *argv, "--workers", "1", "--out", str(serial)],
        cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    (folder,) = [p for p in serial.iterdir() if p.is_dir()]
    pngs = sorted(p.name for p in folder.glob("*.png"))
    assert pngs and pngs == sorted(p.name for p in pooled_folder.glob("*.png"))
    for name in [*pngs, *(v.file_name for v in pooled.videos)]:
        assert (pooled_folder / name).read_bytes() == (folder / name).read_bytes(), name


def _ranking(*agents: str) -> list[RankingRow]:
    return [RankingRow(a, k + 1, 0.5, 1.2, 1, False) for k, a in enumerate(agents)]


def test_the_seed_is_the_first_the_reference_captured_and_models_are_ranked():
    records = [
        record("incremental_ik", 1, None),
        record("incremental_ik", 2, 1.5),
        record("incremental_ik", 3, 1.2),
        record("incremental_ik", 1, None, scenario="drift"),
        record("model_b", 1, 1.0),
        record("model_a", 1, 1.0),
    ]
    ranking = _ranking("model_b", "incremental_ik", "model_a", "hold")
    (paper, drift) = choose_episodes(records, ranking, "incremental_ik", {"model_a", "model_b"})
    assert (paper.scenario, paper.seed, paper.agents) == ("paper", 2, ("incremental_ik", "model_b"))
    assert (drift.scenario, drift.seed) == ("drift", 1)  # captured on none: the first seed
    only = choose_episodes(records, ranking, "incremental_ik", set())  # no trained model
    assert [w.agents for w in only] == [("incremental_ik",), ("incremental_ik",)]
    without = choose_episodes(records[4:5], _ranking("model_b"), "incremental_ik", {"model_b"})
    assert [(w.agents, w.seed) for w in without] == [(("model_b",), 1)]
    assert choose_episodes(records, ranking, "absent", set()) == []


def test_a_suite_without_videos_writes_none_and_a_bad_value_names_the_key(tmp_path):
    suite = tmp_path / "still.yaml"
    suite.write_text("agents: [hold]\nscenarios: [tumbling]\nepisodes: 1\nvideos: false\n")
    assert load_suite(suite).videos is False and load_suite("default").videos is True
    assert main(["--suite", str(suite), "--workers", "1", "--out", str(tmp_path / "r")]) == 0
    report = tmp_path / "r" / "still"
    assert not list(report.glob("*.gif"))
    assert "Episodes to watch" not in (report / "leaderboard.html").read_text()
    suite.write_text("agents: [hold]\nscenarios: [paper]\nepisodes: 1\nvideos: sometimes\n")
    with pytest.raises(SuiteError, match="videos.*true or false"):
        load_suite(suite)


@pytest.mark.parametrize("episodes", ["0", "4"])
def test_video_episodes_outside_the_evaluated_ones_is_one_line_exit_2(episodes, tmp_path, capsys):
    argv = ["--suite", "quick", "--video", str(tmp_path / "v"), "--video-episodes", episodes]
    assert main([*argv, "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--video-episodes {episodes}" in err
    assert not (tmp_path / "r").exists() and not (tmp_path / "v").exists()


def test_video_episodes_without_video_is_one_line_exit_2(tmp_path, capsys):
    assert main(["--suite", "quick", "--video-episodes", "2", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--video-episodes 2" in err and "--video DIR" in err
    assert not (tmp_path / "r").exists()


def test_record_video_writes_an_mp4_over_the_registered_env(tmp_path):
    pytest.importorskip(
        "moviepy",
        reason="gymnasium's RecordVideo needs moviepy: pip install 'capture-bench[video]'",
    )
    from capture_bench.agents import make_agent

    env = gymnasium.make("CaptureBench/Paper-v1", render_mode="rgb_array", render_size=(160, 120))
    env = gymnasium.wrappers.RecordVideo(env, str(tmp_path / "videos"), disable_logger=True)
    agent = make_agent("incremental_ik", env)
    observation, _ = env.reset(seed=PAPER_SEEDS[0])
    done, steps = False, 0
    while not done:
        action, _ = agent.predict(observation, deterministic=True)
        observation, _, terminated, truncated, _ = env.step(np.asarray(action))
        done, steps = terminated or truncated, steps + 1
    env.close()
    (video,) = (tmp_path / "videos").glob("*.mp4")
    assert video.read_bytes()[4:8] == b"ftyp"  # an MP4 container
    from moviepy.video.io.VideoFileClip import VideoFileClip  # the path of moviepy 1 and 2

    clip = VideoFileClip(str(video))
    try:  # a frame after reset and after each step, at the env's render_fps (20)
        assert list(clip.size) == [160, 120] and steps > 1
        assert clip.duration == pytest.approx((steps + 1) / 20, abs=0.06)
    finally:
        clip.close()
