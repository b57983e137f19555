"""Build step that puts the top-level ``configs/`` and ``models/`` inside the wheel.

The project's layout keeps them at the top of the checkout; a wheel carries a copy under
``capture_bench/_data/`` so that a plain ``pip install .`` finds them from any working directory
(`capture_bench.paths`). An editable install reads the checkout's own folders instead.
Everything else about the package is declared in ``pyproject.toml``.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
# What a model directory needs to load safely (policy.pt + metadata.json) and to be understood
# (README.md, its model card); SB3's pickled model.zip stays out of the wheel.
MODEL_FILES = ("policy.pt", "metadata.json", "metadata.yaml", "README.md")


class BuildWithData(build_py):
    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return
        data = Path(self.build_lib) / "capture_bench" / "_data"
        shutil.rmtree(data, ignore_errors=True)
        configs = ROOT / "configs"  # ours (*.yaml) and the RL Zoo's (zoo/*.yml)
        for path in sorted([*configs.glob("*/*.yaml"), *configs.glob("zoo/*.yml")]):
            self._copy(path, data / "configs" / path.relative_to(ROOT / "configs"))
        for model in sorted(p for p in (ROOT / "models").glob("*") if p.is_dir()):
            for name in MODEL_FILES:
                if (model / name).is_file():
                    self._copy(model / name, data / "models" / model.name / name)

    def _copy(self, source: Path, target: Path) -> None:
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)


setup(cmdclass={"build_py": BuildWithData})
