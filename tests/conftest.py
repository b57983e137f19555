"""Shared fixtures: environments that are always closed; an evaluation's report and its data;
headless Chromium for the pages."""

import importlib.util
import os
import shutil
import tempfile
from pathlib import Path

import gymnasium as gym
import pytest
from hypothesis.configuration import set_hypothesis_home_dir

import capture_bench  # noqa: F401  (registers the environments)

# The fuzz tests use no example database (CI sees the same inputs every run); Hypothesis's own
# caches (constants, Unicode tables) go to the temporary folder, not a .hypothesis/ in the checkout.
set_hypothesis_home_dir(Path(tempfile.gettempdir()) / "capture-bench-hypothesis")
# A test's own model.learn() without a logger: SB3 makes an empty folder per call in the temporary
# folder unless SB3_LOGDIR names one; one shared folder instead.
os.environ.setdefault("SB3_LOGDIR", str(Path(tempfile.gettempdir()) / "capture-bench-sb3-logs"))


@pytest.fixture(scope="session")
def load_script():
    """``load_script(name)``: ``scripts/<name>.py`` as a module, registered in ``sys.modules``
    under ``name`` (a dataclass there looks its module up)."""
    import sys

    def _load(name: str):
        path = Path(__file__).resolve().parents[1] / "scripts" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        return module

    return _load


@pytest.fixture
def make_env():
    """Factory for registered envs; closes every env it made."""
    made = []

    def _make(env_id="CaptureBench/Paper-v1", **kwargs):
        env = gym.make(env_id, **kwargs)
        made.append(env)
        return env

    yield _make
    for env in made:
        env.close()


@pytest.fixture(scope="session")
def evaluated():
    """``evaluated(argv, out)`` runs ``evaluate.py`` with ``argv`` (``--out out`` added) and
    returns ``(the ReportData it wrote, the report folder)``."""
    from capture_bench.evaluation import pipeline
    from capture_bench.evaluation.cli import main

    def run(argv: list[str], out: Path):
        seen = {}
        original = pipeline.write_report

        def keep(data, root, images=None):
            seen["data"] = data
            return original(data, root, images)

        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(pipeline, "write_report", keep)
            assert main([*argv, "--out", str(out)]) == 0
        (folder,) = [p for p in out.iterdir() if p.is_dir()]
        return seen["data"], folder

    return run


@pytest.fixture(scope="module")
def browser():
    """Headless Chromium (Debian's ``chromium`` and ``chromium-driver``, which ``.ci/run``
    installs where missing, driven by selenium), its console logged; skipped, with the reason,
    only where it cannot be had. No host name resolves: the pages are read as a machine without
    a network reads them (the documentation site's request for Material's web font fails at once
    and the system font stands in)."""
    try:
        from selenium import webdriver
    except ImportError:
        pytest.skip("selenium is not installed (pip install selenium; it is in the dev extra)")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    if chromium is None or driver_path is None:
        pytest.skip("headless Chromium is not installed: apt-get install chromium chromium-driver")
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                     "--host-resolver-rules=MAP * ~NOTFOUND"):  # fmt: skip
        options.add_argument(argument)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(driver_path))
    yield driver
    driver.quit()


@pytest.fixture(scope="session")
def readme_table():
    """``scripts/readme_table.py`` as a module: the generator of README's and the pages' tables
    and figures."""
    path = Path(__file__).resolve().parents[1] / "scripts" / "readme_table.py"
    spec = importlib.util.spec_from_file_location("readme_table", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
