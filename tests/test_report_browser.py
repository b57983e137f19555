"""The HTML report in a real browser (issue 15 point 4): headless Chromium (Debian's ``chromium``
and ``chromium-driver``, which ``.ci/run`` installs where missing, driven by selenium) opens
``leaderboard.html``: it renders, every image loads (the episodes' GIFs too), and the console shows
no error. Skipped, with the reason, only where Chromium cannot be had."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from capture_bench.evaluation.cli import main

ROOT = Path(__file__).parents[1]


@pytest.fixture(scope="module")
def browser():
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
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"):
        options.add_argument(argument)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(driver_path))
    yield driver
    driver.quit()


def _check_page(driver, page: Path) -> None:
    driver.get(page.resolve().as_uri())
    assert driver.execute_script("return document.readyState") == "complete"
    assert "capture-bench leaderboard" in driver.title + driver.find_element("tag name", "h1").text
    images = driver.execute_script(
        "return Array.from(document.images).map(i => [i.alt, i.complete, i.naturalWidth])"
    )
    assert images, "no image in the page"
    broken = [alt for alt, complete, width in images if not complete or width == 0]
    assert not broken, f"images that did not load: {broken}"
    errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors
    height = driver.execute_script("return document.body.scrollHeight")
    assert height > 1000  # it rendered: headings, tables and figures take room


def test_a_fresh_report_renders_with_every_image_and_no_console_error(browser, tmp_path):
    assert main(["--suite", "quick", "--workers", "1", "--out", str(tmp_path)]) == 0
    _check_page(browser, tmp_path / "quick" / "leaderboard.html")
    gifs = browser.execute_script(  # the episodes to watch (issue 15 point 3), animated
        "return Array.from(document.images).filter(i => i.src.startsWith('data:image/gif'))"
        ".map(i => [i.naturalWidth, i.naturalHeight])"
    )
    assert gifs == [[320, 240], [320, 240]]  # the reference on paper and on tumbling


def test_the_committed_leaderboard_renders_with_every_image_and_no_console_error(browser):
    _check_page(browser, ROOT / "reports" / "published" / "default" / "leaderboard.html")
