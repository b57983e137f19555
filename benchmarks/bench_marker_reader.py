"""Rows per second of the ``marker_keypoints`` features extractor: acting (forward) and fitting
(forward and backward), the reader computing its weights at the windows' pixels (as it does)
and, in the same run, over the whole frame (`MarkerReader.weight_maps`, then `local_centroid`:
the same keypoints). Pin it to one core with ``taskset -c 0``. Usage::

    taskset -c 0 python benchmarks/bench_marker_reader.py                 # 256 rows, 3 frames
    taskset -c 0 python benchmarks/bench_marker_reader.py --rows 64 --frames 1 --repeats 5
"""

from __future__ import annotations

import argparse
import os
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import gymnasium as gym  # noqa: E402 (after the thread settings)
import numpy as np  # noqa: E402
import torch  # noqa: E402

from capture_bench.agents.marker_reader import (  # noqa: E402
    MarkerKeypointExtractor,
    MarkerReader,
    local_centroid,
)


def whole_frame(reader: MarkerReader, x: torch.Tensor):
    """The reading with every pixel's weights computed (the same keypoints)."""
    logits = reader.detect(x)
    peak = logits.flatten(2).argmax(-1)
    pixels, mass = local_centroid(reader.weight_maps(x), reader.window, peak)
    return pixels, mass, logits


def rows_per_second(extractor, batch, repeats: int, backward: bool) -> float:
    start = time.perf_counter()
    for _ in range(repeats):
        if backward:
            extractor(batch).sum().backward()
        else:
            with torch.no_grad():
                extractor(batch)
    return repeats * len(batch["state"]) / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=256)
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--size", type=int, default=84)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    shape = (3 * args.frames, args.size, args.size)
    space = gym.spaces.Dict({"image": gym.spaces.Box(0, 255, shape, np.uint8),
                             "state": gym.spaces.Box(-1, 1, (7,), np.float32)})  # fmt: skip
    extractor = MarkerKeypointExtractor(space)
    batch = {"image": torch.rand(args.rows, *shape), "state": torch.rand(args.rows, 7)}
    windowed = MarkerReader.forward
    print(f"{args.rows} rows of {args.frames} frame(s), {args.size} x {args.size}, one thread")
    for name, forward in (("window pixels", windowed), ("whole frame", whole_frame)):
        MarkerReader.forward = forward
        act = rows_per_second(extractor, batch, args.repeats, backward=False)
        fit = rows_per_second(extractor, batch, args.repeats, backward=True)
        print(f"  weights at the {name:14s} act {act:7.0f} rows/s   fit {fit:7.0f} rows/s")
    MarkerReader.forward = windowed


if __name__ == "__main__":
    main()
