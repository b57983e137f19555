"""Where capture-bench finds its configuration files and its shipped models.

Both live at the top of the checkout (``configs/``, ``models/``), and a wheel carries a copy of
them inside the package (``capture_bench/_data/``, written by ``setup.py``'s build step), so a
plain ``pip install .`` registers every scenario from any working directory. Lookup order:

1. the environment variable (``CAPTURE_BENCH_CONFIGS``, ``CAPTURE_BENCH_MODELS``), read once when
   ``capture_bench`` is imported: point it at your own folder of scenario, suite and algorithm
   files, or of models;
2. the copy inside an installed wheel (``capture_bench/_data/configs``, ``.../models``);
3. the checkout the package was imported from (``<checkout>/configs``, ``<checkout>/models``:
   an editable install or a source tree).

A user's own files are always usable by path as well (``--scenarios my.yaml``,
``--suite my_suite.yaml``, ``--config my_ppo.yaml``, ``--agents path/to/model``).
"""

from __future__ import annotations

import os
from pathlib import Path

CONFIGS_ENV = "CAPTURE_BENCH_CONFIGS"
MODELS_ENV = "CAPTURE_BENCH_MODELS"
#: The folder of a model's training seeds' policies, ``<model>/seeds/<seed>/`` (the model card's
#: ``seeds`` entry names them): what `capture_bench.training.train.model_card` writes and the
#: evaluation reads.
SEEDS_DIR = "seeds"
PACKAGE_DIR = Path(__file__).resolve().parent
BUNDLED_DIR = PACKAGE_DIR / "_data"  # exists only in an installed wheel
CHECKOUT_DIR = PACKAGE_DIR.parent


def _find(variable: str, name: str) -> Path:
    override = os.environ.get(variable)
    if override:
        return Path(override).expanduser().resolve()
    bundled = BUNDLED_DIR / name
    return bundled if bundled.is_dir() else CHECKOUT_DIR / name


def config_dir() -> Path:
    """The folder holding ``scenarios/``, ``suites/`` and ``algos/``."""
    return _find(CONFIGS_ENV, "configs")


def models_dir() -> Path:
    """The folder of shipped models (``models/<name>/`` with ``policy.pt`` + ``metadata.json``)."""
    return _find(MODELS_ENV, "models")
