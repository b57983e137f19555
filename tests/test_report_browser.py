"""The HTML report in a real browser: headless Chromium (Debian's ``chromium`` and
``chromium-driver``, which ``.ci/run`` installs where missing, driven by selenium) opens
``leaderboard.html`` at a desktop's 1280 px and, as a phone, at 390 px. It renders, every image
loads (the episodes' GIFs too) and the console shows no error; the first screen says what a
capture is (`report_capture_rule`, verbatim) and shows the ranking; every image is a figure with
a caption that says what it shows, at its natural size on the desktop; the contents' links all
land; and on the phone the page never scrolls sideways (tables and code scroll inside their own
boxes). Pages checked: a fresh ``--suite quick`` report, the committed published report, and the
published report drawn again by this code from the committed folder's ``episodes.csv`` and
``results.json``. Skipped, with the reason, only where Chromium cannot be had."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import re
from pathlib import Path

import pytest

from capture_bench.evaluation.cli import main
from capture_bench.evaluation.reporting.aggregate import rank_agents, summarise_all
from capture_bench.evaluation.reporting.merge import carried_videos
from capture_bench.evaluation.reporting.report import (
    ReportData,
    figure_names,
    figures,
    html_page,
    report_capture_rule,
)
from capture_bench.evaluation.reporting.report_folder import read_report
from capture_bench.evaluation.running.suites import load_suite

ROOT = Path(__file__).parents[1]
PUBLISHED = ROOT / "reports" / "published" / "default"
DESKTOP, PHONE = (1280, 900), (390, 844)
FILE_NAME = re.compile(r"^[\w.()-]+\.(png|gif)$")


def report_data(folder: Path) -> ReportData:
    """The report ``evaluate.py`` wrote into ``folder``, read back from its ``episodes.csv`` and
    ``results.json`` and aggregated again (its GIFs taken as they are): what the report's pages
    are drawn from."""
    source = read_report(folder)
    results = json.loads((folder / "results.json").read_text())
    summaries = summarise_all(source.records, source.reference)
    privileged = {a["label"] for a in source.agents if a["privileged"]}
    unranked = sorted({name for row in results["ranking"] for name in row["unranked"]})
    ranking = rank_agents(summaries, privileged, unranked=unranked)
    assert [r.agent for r in ranking] == [row["agent"] for row in results["ranking"]]
    description = ""
    with contextlib.suppress(Exception):  # a custom or merged report has no suite file
        description = load_suite(source.suite).description
    data = ReportData(source.suite, description, results["command"], source.reference,
                      source.records, summaries, ranking, results["provenance"])  # fmt: skip
    learned = {a["label"] for a in source.agents if a["kind"] == "model"}
    videos, _ = carried_videos([source], data, learned)
    return dataclasses.replace(data, videos=videos)


def _open(driver, page: Path, size: tuple[int, int], phone: bool) -> None:
    width, height = size
    metrics = {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": phone}
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", metrics)
    driver.get(page.resolve().as_uri())
    assert driver.execute_script("return document.readyState") == "complete"


def _check_page(driver, page: Path) -> None:
    _open(driver, page, DESKTOP, phone=False)
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


def _check_desktop(driver, page: Path, rule: str) -> None:
    """At 1280 x 900: the first screen, the figures and their captions, the contents."""
    _open(driver, page, DESKTOP, phone=False)
    top = driver.execute_script(
        "const p = document.querySelector('h1 + p');"
        "const h = Array.from(document.querySelectorAll('h2'))"
        "  .find(h => h.textContent === 'Overall ranking');"
        "return [p.textContent, p.getBoundingClientRect().bottom,"
        "        h ? h.getBoundingClientRect().top : null,"
        "        h ? h.nextElementSibling.querySelector('table') !== null : false]"
    )
    sentence, bottom, ranking, table = top
    assert sentence == rule and bottom <= DESKTOP[1], (sentence, bottom)
    assert ranking is not None and ranking < DESKTOP[1] and table, "the ranking is not next"
    shown = driver.execute_script(
        "return Array.from(document.images).map(i => {"
        "  const f = i.closest('figure'), c = f && f.querySelector('figcaption');"
        "  return [i.alt, c ? c.textContent.trim() : null, i.naturalWidth, i.clientWidth,"
        "          i.src.slice(0, 14)]})"
    )
    for alt, caption, natural, width, source in shown:
        assert caption, f"an image without a figure caption: {alt!r}"
        assert not FILE_NAME.match(caption) and not FILE_NAME.match(alt), (alt, caption)
        assert alt.strip() and len(caption.split()) >= 5  # words, saying what it shows
        if source == "data:image/png":  # drawn for this column: text at its drawn size
            assert width >= 0.95 * natural, f"{alt[:50]!r} shrunk from {natural} to {width} px"
    links, sections, missing = driver.execute_script(
        "const links = Array.from(document.querySelectorAll('nav.toc a'))"
        "  .map(a => a.getAttribute('href'));"
        "const sections = Array.from(document.querySelectorAll('section[id]')).map(s => s.id);"
        "return [links, sections,"
        "        links.filter(l => !l.startsWith('#') || !document.getElementById(l.slice(1)))]"
    )
    assert links and not missing, f"contents links that land nowhere: {missing}"
    assert sorted(links) == sorted(f"#{s}" for s in sections)  # every section is in it
    if any(source == "data:image/gif" for *_, source in shown):
        assert "#watch" in links  # the episodes to watch


def _check_phone(driver, page: Path) -> None:
    """At 390 px as a phone: the viewport is the phone's, nothing but tables and code scrolls
    sideways, and those inside their own boxes."""
    _open(driver, page, PHONE, phone=True)
    inner, scroll, tables, pres, images = driver.execute_script(
        "const box = e => [getComputedStyle(e).overflowX, e.getBoundingClientRect().right];"
        "return [window.innerWidth, document.documentElement.scrollWidth,"
        "  Array.from(document.querySelectorAll('table')).map(t => box(t.parentElement)),"
        "  Array.from(document.querySelectorAll('pre')).map(box),"
        "  Array.from(document.images).map(i => i.getBoundingClientRect().right)]"
    )
    assert inner == PHONE[0], f"the page is laid out {inner} px wide on a {PHONE[0]} px phone"
    assert scroll <= inner, f"the page scrolls sideways: {scroll} px wide in {inner}"
    for overflow, right in tables + pres:
        assert overflow in ("auto", "scroll") and right <= inner + 0.5, (overflow, right)
    assert tables and max(images) <= inner + 0.5


@pytest.fixture(scope="module")
def fresh(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fresh")
    assert main(["--suite", "quick", "--workers", "1", "--out", str(out)]) == 0
    return out / "quick"


def test_a_fresh_report_renders_with_every_image_and_no_console_error(browser, fresh):
    _check_page(browser, fresh / "leaderboard.html")
    gifs = browser.execute_script(  # the episodes to watch, animated
        "return Array.from(document.images).filter(i => i.src.startsWith('data:image/gif'))"
        ".map(i => [i.naturalWidth, i.naturalHeight])"
    )
    assert gifs == [[320, 240], [320, 240]]  # the reference on paper and on tumbling


def test_a_fresh_report_reads_on_a_desktop_and_on_a_phone(browser, fresh):
    rule = report_capture_rule(report_data(fresh))
    _check_desktop(browser, fresh / "leaderboard.html", rule)
    _check_phone(browser, fresh / "leaderboard.html")


def test_the_published_report_drawn_again_from_its_episodes_reads_on_both(browser, tmp_path):
    data = report_data(PUBLISHED)
    images = figures(data)
    assert sorted(images) == sorted(p.name for p in PUBLISHED.glob("*.png"))  # names kept
    page = tmp_path / "leaderboard.html"
    page.write_text(html_page(data, images))
    _check_page(browser, page)
    _check_desktop(browser, page, report_capture_rule(data))
    _check_phone(browser, page)
    assert sorted(figure_names(data)) == sorted(images)


def test_the_committed_leaderboard_renders_and_reads_on_a_desktop_and_a_phone(browser):
    page = PUBLISHED / "leaderboard.html"
    _check_page(browser, page)
    _check_desktop(browser, page, report_capture_rule(report_data(PUBLISHED)))
    _check_phone(browser, page)
