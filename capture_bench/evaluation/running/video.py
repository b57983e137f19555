"""Episodes on video: one evaluation episode, rendered by pybullet, as an animated GIF.

An episode is recorded through the evaluation's own path: `backends.run_task` (the agent
resolved and built as for the tables, seeded with the episode's seed, ``reset(seed=seed)``, then
``predict``/``step`` by `rollout.run_episode`) on an environment of the same scenario with
``reuse_target_side``, which differs from a worker's only in rendering at `FRAME_SIZE`. So a
video shows the episode of ``episodes.csv`` with that seed, and its record equals the table's row
(``tests/test_video.py``).

Each frame is pybullet's image with the target's trace (red) and the end-effector's (blue) drawn
over it (`CaptureEnv.render`), under a caption: agent, scenario, seed, the simulated time,
and on the last frame the outcome. Pillow writes the GIF: one palette for every frame (no
flicker, small files), played at `SPEED` x real time, the last frame held `HOLD_S` s.
An episode of more than `MAX_FRAMES` steps shows every k-th step (and the last).
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from capture_bench.evaluation.running.backends import EpisodeTask, make_env, run_task, task_spec
from capture_bench.evaluation.running.rollout import EpisodeRecord
from capture_bench.files import atomic_write, episode_file_name

#: Frame size, (width, height) pixels: readable, and small in the GIF.
FRAME_SIZE = (320, 240)
#: Most frames in a GIF; a longer episode shows every ceil(steps / MAX_FRAMES)-th step.
MAX_FRAMES = 100
#: Playback speed, x real time: the paper scenario's captures take 1-3 s, too quick to follow.
SPEED = 0.5
#: How long the last frame (the capture, or the failure) stays, s of playback.
HOLD_S = 1.5
#: Colours of the GIF's one palette (quantised from the first and last frames, no dithering).
PALETTE_COLOURS = 64
CAPTION_HEIGHT = 30  # pixels of the caption strip over the top of each frame


@dataclass(frozen=True)
class EpisodeVideo:
    """One recorded episode.

    Attributes:
        record: the episode's record, as in ``episodes.csv``.
        gif: the animated GIF's bytes.
        frames: number of frames in the GIF.
    """

    record: EpisodeRecord
    gif: bytes
    frames: int

    @property
    def file_name(self) -> str:
        """``<agent>_<scenario>_seed<seed>.gif``."""
        r = self.record
        return episode_file_name(r.agent, r.scenario, r.seed, ".gif")

    def caption(self) -> str:
        """Agent, scenario, seed and outcome:
        ``dagger-dls-all · paper · seed 1000000 · captured at 1.45 s``."""
        r = self.record
        return f"{r.agent} · {r.scenario} · seed {r.seed} · {outcome_text(r)}"


def outcome_text(record: EpisodeRecord) -> str:
    """``captured at 1.23 s`` or ``failed (reason) at 4.50 s`` (simulated time)."""
    if record.captured:
        return f"captured at {record.capture_time:.2f} s"
    return f"failed ({record.failure}) at {record.end_time:.2f} s"


class FrameRecorder(gymnasium.Wrapper):
    """Keeps ``render()``'s image after ``reset`` and after every ``stride``-th step and the last
    one, with the simulated time of each (``info["time"]``, s). The env must render
    ``rgb_array``; actions, observations and ``info`` pass through unchanged."""

    def __init__(self, env: gymnasium.Env, stride: int = 1) -> None:
        super().__init__(env)
        self.stride = max(1, int(stride))
        self.frames: list[np.ndarray] = []
        self.times: list[float] = []
        self._steps = 0

    def reset(self, **kwargs: Any) -> Any:
        observation, info = self.env.reset(**kwargs)
        self.frames, self.times, self._steps = [], [], 0
        self._keep(info)
        return observation, info

    def step(self, action: Any) -> Any:
        observation, reward, terminated, truncated, info = self.env.step(action)
        self._steps += 1
        if terminated or truncated or self._steps % self.stride == 0:
            self._keep(info)
        return observation, reward, terminated, truncated, info

    def _keep(self, info: dict[str, Any]) -> None:
        self.frames.append(np.asarray(self.env.render()))
        self.times.append(float(info.get("time", math.nan)))


def frame_stride(steps: int | None, max_frames: int = MAX_FRAMES) -> int:
    """Keep every k-th step so that an episode of ``steps`` steps has at most ``max_frames``
    frames after the first (1 when ``steps`` is not known)."""
    return 1 if not steps else max(1, math.ceil(steps / max_frames))


def record_video(
    task: EpisodeTask, steps: int | None = None, size: tuple[int, int] = FRAME_SIZE
) -> EpisodeVideo:
    """Run ``task``'s episode again, rendered, and make its GIF.

    Args:
        task: agent spec, scenario, seed (as evaluated).
        steps: the episode's length if known (its ``episodes.csv`` row), to thin the frames of a
            long episode to `MAX_FRAMES`; None renders every step.
        size: frame (width, height), pixels.
    """
    env = make_env(
        task.scenario,
        reuse_target_side=True,
        render_mode="rgb_array",
        render_size=size,
        **task_spec(task).env_options(),
    )
    recorder = FrameRecorder(env, frame_stride(steps))
    try:
        record, _ = run_task(task, env=recorder)
    finally:
        recorder.close()
    frames, times = recorder.frames, recorder.times
    captioned = [
        _with_caption(frame, record, time, last=i == len(frames) - 1)
        for i, (frame, time) in enumerate(zip(frames, times))
    ]
    return EpisodeVideo(record, gif_bytes(captioned, _durations_ms(times)), len(frames))


def _durations_ms(times: Sequence[float], fps: float = 20.0) -> list[int]:
    """Display time of each frame, ms: the simulated time to the next frame over `SPEED`
    (1/fps where unknown), in the GIF's 10 ms units, at least 20 ms (browsers show shorter
    delays as 100 ms); the last frame `HOLD_S`."""
    out = []
    for now, after in zip(times[:-1], times[1:]):
        seconds = (after - now) if math.isfinite(after - now) and after > now else 1.0 / fps
        out.append(max(20, 10 * round(100 * seconds / SPEED)))
    return [*out, round(1000 * HOLD_S)]


def _with_caption(frame: np.ndarray, record: EpisodeRecord, time: float, last: bool) -> Any:
    """The frame as a Pillow image with a two-line caption strip over its top."""
    from PIL import Image, ImageDraw, ImageFont

    image = Image.fromarray(frame)
    draw = ImageDraw.Draw(image)
    draw.rectangle((0, 0, image.width, CAPTION_HEIGHT - 1), fill=(255, 255, 255))
    font = ImageFont.load_default(size=11)
    draw.text((4, 2), f"{record.agent} · {record.scenario} · seed {record.seed}", (0, 0, 0), font)
    status = outcome_text(record) if last else f"t = {time:.2f} s"
    draw.text((4, 15), status, (0, 0, 0) if not last else (150, 0, 0), font)
    return image


def gif_bytes(images: Sequence[Any], durations_ms: Sequence[int]) -> bytes:
    """An endlessly looping GIF of Pillow RGB ``images`` with one palette, no dithering."""
    from PIL import Image

    first, last = images[0], images[-1]
    both = Image.new("RGB", (first.width + last.width, max(first.height, last.height)))
    both.paste(first, (0, 0))
    both.paste(last, (first.width, 0))  # the last frame holds every trace and the outcome
    palette = both.quantize(PALETTE_COLOURS, method=Image.Quantize.MEDIANCUT)
    frames = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in images]
    buffer = io.BytesIO()
    frames[0].save(
        buffer,
        format="GIF",
        save_all=True,
        append_images=frames[1:],
        duration=list(durations_ms),
        loop=0,
    )
    return buffer.getvalue()


def write_videos(videos: Sequence[EpisodeVideo], directory: Path) -> list[Path]:
    """Write each video's GIF into ``directory`` (created) as its `EpisodeVideo.file_name`,
    each file whole; returns the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for video in videos:
        path = directory / video.file_name
        atomic_write(path, video.gif)
        paths.append(path)
    return paths
