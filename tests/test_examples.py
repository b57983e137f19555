"""``examples/my_agent.py`` is evaluated by the commands ``docs/agents.md`` gives for it, as
written there: each runs (``python evaluate.py`` from the repository's root, here the script by
its path from an empty folder so the report lands there) and its report ranks the example, which
captures."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
SPEC = "examples.my_agent:MyAgent"


def documented_commands() -> list[str]:
    """The ``python evaluate.py`` lines of docs/agents.md's bash blocks that name the example."""
    text = (ROOT / "docs" / "agents.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", text, flags=re.S)
    lines = [line.split("#")[0].strip() for block in blocks for line in block.splitlines()]
    return [line for line in lines if line.startswith("python evaluate.py") and SPEC in line]


def test_the_docs_give_the_examples_commands():
    commands = documented_commands()
    assert f"python evaluate.py --agents {SPEC}" in commands  # the default suite
    assert len(commands) == 3


@pytest.mark.parametrize("command", documented_commands())
def test_the_example_agent_is_evaluated_by_the_documented_command(command, tmp_path):
    argv = shlex.split(command)
    assert argv[:2] == ["python", "evaluate.py"]
    done = subprocess.run(
        [sys.executable, str(ROOT / "evaluate.py"), *argv[2:]],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    (report,) = (tmp_path / "reports").iterdir()
    results = json.loads((report / "results.json").read_text())
    row = next(r for r in results["ranking"] if r["agent"] == SPEC)
    assert row["rank"] is not None  # ranked beside the others, not a reference
    assert row["mean_capture_rate"] > 0.8  # a real controller: it captures under the envelope
