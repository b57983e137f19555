"""Instructions per env step, counted by valgrind: a figure the machine's load cannot move.

Wall-clock and CPU time on a shared machine swing by tens of percent from one run to the next;
the number of instructions a fixed piece of work executes does not. This script plays
``benchmarks/bench_steps.py``'s work (seeded episodes, small random actions from one seed, resets
included) under ``valgrind --tool=callgrind`` twice, ``--steps`` steps of each scenario and none,
and prints the difference divided by the steps: the instructions of one env step (start-up,
imports and a warm-up episode cancel out)::

    python benchmarks/count_instructions.py --num-envs 1 --steps 1500
    python benchmarks/count_instructions.py --package /path/to/other/checkout --num-envs 1

``--package`` counts another checkout of the package (for instance a ``git worktree`` of an older
commit), with this script's own stepping code, so two versions are compared on the same work.
Instructions are not time (a cache miss or a BLAS call costs more than its count), but where two
versions do the same kind of work, their ratio is the steadiest comparison this machine allows.
Needs ``valgrind`` on ``PATH``; each count runs about 50 times slower than the work itself.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SCENARIOS = ("paper", "noisy")


def instructions(package: Path, num_envs: int, steps: int) -> int:
    """Instructions the whole process executes: import ``package``'s ``capture_bench``, a warm-up
    of 100 steps, then ``steps`` steps of each of `SCENARIOS` (`bench_steps`)."""
    program = (
        "import sys\n"
        f"sys.path[:0] = [{str(package)!r}, {str(HERE)!r}]\n"
        "import bench_steps\n"
        f"play = (lambda s, n: bench_steps.single(s, n)) if {num_envs} == 1 else "
        f"(lambda s, n: bench_steps.vector(s, {num_envs}, n))\n"
        "play('paper', 100)\n"
        f"for name in {SCENARIOS!r}:\n"
        f"    if {steps}: play(name, {steps})\n"
    )
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run(
            [
                "valgrind",
                "--tool=callgrind",
                f"--callgrind-out-file={tmp}/callgrind.out",
                sys.executable,
                "-c",
                program,
            ],
            capture_output=True,
            text=True,
            env=env,
            check=False,
        )
    found = re.search(r"Collected\s*:\s*(\d+)", out.stderr)
    if out.returncode != 0 or found is None:
        raise SystemExit(f"valgrind failed (exit {out.returncode}):\n{out.stderr[-2000:]}")
    return int(found.group(1))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--package", type=Path, default=HERE.parent, help="checkout whose capture_bench to count"
    )
    parser.add_argument("--num-envs", type=int, default=1, help="1: CaptureEnv; more: vector")
    parser.add_argument("--steps", type=int, default=1500, help="steps of each scenario")
    args = parser.parse_args(argv)
    if shutil.which("valgrind") is None:
        parser.error("valgrind is not on PATH (apt install valgrind)")
    if not (args.package / "capture_bench" / "__init__.py").is_file():
        parser.error(f"--package {args.package} holds no capture_bench/__init__.py")
    if args.num_envs < 1 or args.steps < 1:
        parser.error("--num-envs and --steps must be >= 1")
    none = instructions(args.package, args.num_envs, 0)
    some = instructions(args.package, args.num_envs, args.steps)
    env_steps = args.steps * len(SCENARIOS) * args.num_envs
    print(f"package {args.package}, {args.num_envs} env(s), {' and '.join(SCENARIOS)}")
    print("figure  instructions_per_env_step")
    print(f"step  {(some - none) / env_steps:.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
