"""The built documentation site in a real browser: ``mkdocs build --strict`` into a temporary
folder, then headless Chromium (driven by selenium, as in ``tests/test_report_browser.py``) opens
every page at 1280 and 390 px wide. Every image loads; no page scrolls sideways (a wide table
scrolls inside its own box, code wraps inside its box, a text block such as a diagram scrolls
inside its box); the leaderboard's tables fit at 1280 px; the home page and the results page show the published report's heatmap and ranking,
and the results page links the full HTML report, which the site carries. The built HTML holds no
raw Sphinx role. Skipped, with the reason, where mkdocs or Chromium cannot be had.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote, urlparse

import pytest

ROOT = Path(__file__).resolve().parents[1]
WIDTHS = (1280, 390)  # px: a laptop, a phone
SPHINX_ROLE = re.compile(r":(class|meth|func|mod|attr|data|exc|obj):")
REPORT_FIGURES = ("summary_heatmap.png", "summary_ranking.png")

#: Per page: the page's width against the window's, images that did not load, code boxes whose
#: text runs past their right edge (a block without a language, ``text``: a diagram, scrolls in
#: its box instead), and tables wider than their scrolling box.
PAGE_STATE = """
const boxes = sel => Array.from(document.querySelectorAll(sel));
return {
  scrollWidth: document.documentElement.scrollWidth,
  innerWidth: window.innerWidth,
  broken: Array.from(document.images)
    .filter(i => !i.complete || i.naturalWidth === 0).map(i => i.getAttribute('src')),
  images: Array.from(document.images)
    .filter(i => i.naturalWidth > 0).map(i => i.getAttribute('src')),
  codeOverflow: boxes('.highlight:not(.language-text) pre > code')
    .filter(c => c.scrollWidth > c.clientWidth + 1)
    .map(c => c.textContent.split('\\n')[0].slice(0, 60)),
  tableOverflow: boxes('.md-typeset__scrollwrap').filter(w => w.scrollWidth > w.clientWidth + 1)
    .map(w => w.querySelector('th') ? w.querySelector('th').textContent : ''),
  links: Array.from(document.links).map(a => a.href),
};
"""


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    if importlib.util.find_spec("mkdocs") is None:
        pytest.skip("mkdocs is not installed: pip install -e '.[docs]'")
    out = tmp_path_factory.mktemp("site")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    return out


def pages(site: Path) -> list[Path]:
    """Every page of the site (``use_directory_urls``: ``x/index.html``), the home page first."""
    found = sorted(
        path for path in site.rglob("index.html") if path.relative_to(site).parts[0] != "assets"
    )
    return sorted(found, key=lambda path: path != site / "index.html")


def _open(driver, page: Path, width: int) -> dict:
    driver.set_window_size(width, 900)
    driver.get(page.as_uri())
    state = driver.execute_script(PAGE_STATE)
    assert state["innerWidth"] == width, f"the window is {state['innerWidth']} px, not {width}"
    return state


def test_the_built_site_holds_no_raw_sphinx_role(site):
    for page in site.rglob("*.html"):
        found = SPHINX_ROLE.search(page.read_text(errors="replace"))
        assert found is None, f"{page.relative_to(site)}: raw Sphinx role {found.group(0)!r}"


def test_the_api_page_names_every_built_in_agent(site):
    from capture_bench.agents import AGENTS

    page = (site / "api" / "agents" / "index.html").read_text()
    missing = [name for name in AGENTS if f"<code>{name}</code>" not in page]
    assert not missing, f"AGENTS's docstring does not list {missing}"
    assert "_public(" not in re.sub(r"<[^>]+>", "", page), "AGENTS is shown as its raw value"


def test_every_page_loads_its_images_and_never_scrolls_sideways(site, browser):
    listed = pages(site)
    assert len(listed) > 20 and site / "results" / "leaderboard" / "index.html" in listed
    problems = []
    for width in WIDTHS:
        for page in listed:
            state = _open(browser, page, width)
            name = f"{page.parent.relative_to(site).as_posix() or 'home'} at {width} px"
            if state["broken"]:
                problems.append(f"{name}: images that did not load: {state['broken']}")
            if state["scrollWidth"] > state["innerWidth"]:
                problems.append(f"{name}: the page is {state['scrollWidth']} px wide")
            if state["codeOverflow"]:
                problems.append(f"{name}: code past its box: {state['codeOverflow']}")
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("page", ["index.html", "results/leaderboard/index.html"])
def test_the_home_and_results_pages_show_the_reports_figures(site, browser, page):
    for width in WIDTHS:
        shown = [Path(src).name for src in _open(browser, site / page, width)["images"]]
        for figure in REPORT_FIGURES:
            assert figure in shown, f"{page} at {width} px does not show {figure}: {shown}"
        assert any(name.endswith(".gif") for name in shown), f"{page}: no episode GIF"


def test_the_results_page_links_the_full_report_and_its_tables_fit(site, browser):
    state = _open(browser, site / "results" / "leaderboard" / "index.html", 1280)
    assert not state["tableOverflow"], f"tables wider than the column: {state['tableOverflow']}"
    reports = [link for link in state["links"] if link.endswith("/leaderboard.html")]
    assert reports, "the results page does not link leaderboard.html"
    for link in reports:
        target = Path(unquote(urlparse(link).path))
        assert target.is_file() and site in target.parents, f"{link} is not a file of the site"
        assert (
            target.read_bytes()
            == (ROOT / "reports" / "published" / "default" / "leaderboard.html").read_bytes()
        ), "the site's leaderboard.html is not the published report's"
