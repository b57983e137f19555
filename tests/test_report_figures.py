"""The report's figures and page, without a browser: each figure is drawn for the number of agents
it holds (height grows with them, no two tick labels overlap, no text under 8 pt = 10 px, widths
within the page's column), each agent keeps one distinct colour, the probability-of-improvement
matrix holds the top agents only, the heatmap's colours tell 86% from 100%, the ranking figure's
axes resolve the top agents, every figure has a caption that says what it shows, and the
per-scenario tables follow the ranking."""

from __future__ import annotations

import math
import re
import struct
from types import SimpleNamespace

import numpy as np
import pytest

from capture_bench.evaluation.reporting import plots, report
from capture_bench.evaluation.reporting.aggregate import rank_agents, summarise_all
from capture_bench.evaluation.reporting.report import (
    DETAIL_HEADER,
    MAIN_HEADER,
    READING,
    ReportData,
    figure_groups,
    figure_names,
    figure_text,
    figures,
    html_page,
    markdown,
    report_capture_rule,
    scenario_summaries,
)
from tests.records import record

SEEDS = range(8)
SCENARIOS = ("s1", "s2", "s3")
LONG = "-with-a-name-as-long-as-a-model"  # agent names as long as the shipped models'


def _report(n: int) -> ReportData:
    """``n`` agents on three scenarios, 8 seeds each: agent k captures fewer episodes, more
    slowly, the larger k (the last two never); the records list the agents in reverse, so the
    order of the summaries is not the ranking's."""
    names = [f"a{k:02d}{LONG}" for k in range(n)]
    records = []
    for k in reversed(range(n)):
        for scenario in SCENARIOS:
            for seed in SEEDS:
                caught = k < n - 2 and (seed + k) % (k + 1) < 8 - k % 8
                records.append(record(names[k], scenario, seed, 1.05 + 0.1 * k + 0.02 * seed
                                       if caught else None))  # fmt: skip
    summaries = summarise_all(records, reference_agent=names[0])
    ranking = rank_agents(summaries, (), records=records)
    return ReportData(f"synthetic-{n}", "synthetic records", "python evaluate.py", names[0],
                      records, summaries, ranking, {"seeds": {}})  # fmt: skip


def _png_size(png: bytes) -> tuple[int, int]:
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
    return struct.unpack(">II", png[16:24])


def _tick_label_overlaps(fig) -> list[tuple[str, str]]:
    """The pairs of tick labels, over every axes of ``fig``, whose boxes overlap (by more than
    half a pixel each way)."""
    renderer = fig.canvas.get_renderer()
    labels = []
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        for text in [*ax.get_xticklabels(), *ax.get_yticklabels()]:
            if text.get_visible() and text.get_text().strip():
                labels.append((text.get_text(), text.get_window_extent(renderer)))
    out = []
    for i, (a, box_a) in enumerate(labels):
        for b, box_b in labels[:i]:
            wide = min(box_a.x1, box_b.x1) - max(box_a.x0, box_b.x0)
            high = min(box_a.y1, box_b.y1) - max(box_a.y0, box_b.y0)
            if wide > 0.5 and high > 0.5:
                out.append((a, b))
    return out


def _smallest_text(fig) -> float:
    from matplotlib.text import Text

    sizes = [t.get_fontsize() for t in fig.findobj(Text) if t.get_visible() and t.get_text()]
    return min(sizes)


@pytest.fixture(scope="module")
def drawn():
    """Every figure of a 5-agent and a 25-agent report: ``{n: {name: (png, overlaps, smallest
    font size)}}``, each figure checked as it is saved."""
    checked: dict = {}
    save = plots._png

    def inspect(fig) -> bytes:
        fig.canvas.draw()
        checked["last"] = (_tick_label_overlaps(fig), _smallest_text(fig))
        return save(fig)

    out: dict = {}
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(plots, "_png", inspect)
        for n in (5, 25):
            data = _report(n)
            out[n] = {}
            for name in figure_names(data):
                png = figures(data, [name])[name]
                out[n][name] = (png, *checked.pop("last"))
    return out


def test_every_figure_grows_with_its_agents_and_no_tick_labels_overlap(drawn):
    for n, pictures in drawn.items():
        for name, (png, overlaps, smallest) in pictures.items():
            assert not overlaps, f"{name} with {n} agents: overlapping tick labels {overlaps[:3]}"
            assert smallest >= 8, f"{name} with {n} agents: text at {smallest} pt"
            width, _ = _png_size(png)  # shown unscaled in the page's column on a desktop
            assert width <= (plots.MAX_WIDTH_INCHES + 0.6) * plots.DPI, (name, n, width)
    grows = ["summary_heatmap.png", "summary_ranking.png", "summary_improvement.png",
             "failures_by_reason.png", "ratio_to_limit.png", "survival_s1.png",
             "performance_profile.png"]  # fmt: skip
    for name in grows:
        few, many = (_png_size(drawn[n][name][0])[1] for n in (5, 25))
        assert many > few, f"{name}: {few} px high with 5 agents, {many} px with 25"
    # a row of the heatmap and of the bar and box figures keeps its height
    for name in ("summary_heatmap.png", "failures_by_reason.png"):
        few, many = (_png_size(drawn[n][name][0])[1] for n in (5, 25))
        assert many - few >= 20 * plots.ROW_INCHES * plots.DPI, name


def test_each_agent_has_one_distinct_colour_up_to_30_and_one_style_up_to_40():
    def lab(colour: str) -> np.ndarray:
        from matplotlib.colors import to_rgb

        rgb = np.array(to_rgb(colour))
        linear = np.where(rgb > 0.04045, ((rgb + 0.055) / 1.055) ** 2.4, rgb / 12.92)
        xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722],
                        [0.0193, 0.1192, 0.9505]]) @ linear / [0.95047, 1.0, 1.08883]  # fmt: skip
        f = np.where(xyz > 0.008856, np.cbrt(xyz), 7.787 * xyz + 16 / 116)
        return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])

    for n in range(1, 31):
        agents = [f"agent {k}" for k in range(n)]
        colours = plots.agent_colours(agents)
        assert len(set(colours.values())) == n
        with_reference = plots.agent_colours(agents, reference="agent 3")
        assert len(set(with_reference.values())) == n
        if n > 3:
            assert with_reference["agent 3"] == plots.REFERENCE_COLOUR
    points = [lab(c) for c in (*plots.PALETTE, plots.REFERENCE_COLOUR)]
    nearest = min(np.linalg.norm(a - b) for i, a in enumerate(points) for b in points[:i])
    assert len(plots.PALETTE) >= 30 and nearest >= 20  # distinct to the eye, not only in hex
    agents = [f"agent {k}" for k in range(40)]
    colours, styles = plots.agent_colours(agents), plots.agent_line_styles(agents)
    assert len({(colours[a], styles[a]) for a in agents}) == 40
    # the same agent, the same colour in every figure: the report hands one map to all
    data = _report(5)
    assert plots.agent_colours(report._agents(data), data.reference)[data.reference] == "#000000"


def test_the_improvement_matrix_holds_the_top_agents_and_its_caption_says_so(monkeypatch):
    data = _report(14)
    seen = {}

    def capture(matrix, agents):
        seen["matrix"], seen["agents"] = matrix, agents
        return b"\x89PNG"

    monkeypatch.setattr(plots, "improvement_figure", capture)
    figures(data, ["summary_improvement.png"])
    top = [r.agent for r in data.ranking][: plots.IMPROVEMENT_TOP]
    assert seen["agents"] == top and seen["matrix"].shape == (10, 10)
    text = figure_text(data, "summary_improvement.png")
    assert "top 10 agents by rank (of 14" in text.alt and text.caption.startswith(text.alt)
    small = _report(4)
    assert "(of" not in figure_text(small, "summary_improvement.png").alt


def test_the_heatmap_tells_86_from_100_percent_and_99_from_100():
    classes = plots.rate_classes()
    index = {rate: plots.rate_class(rate) for rate in (0.0, 0.5, 0.86, 0.95, 0.99, 1.0)}
    assert len(set(index.values())) == 6 and index[1.0] == len(classes) - 1
    assert classes[int(index[0.86])] == "75%–90%" and classes[-1] == "100%"
    assert math.isnan(plots.rate_class(math.nan))
    assert plots._percent(0.995) == "99.5%" and plots._percent(1.0) == "100%"


def _row(agent: str, rank: int, value: float, low: float, high: float, tie=None):
    first, last = tie or (rank, rank)
    line = SimpleNamespace(agent=agent, rank=rank, rank_low=first, rank_high=last,
                           tied=tie is not None, tie_first=first, tie_last=last)  # fmt: skip
    return SimpleNamespace(agent=agent, mean_capture_rate=value, low=low, high=high,
                           tied_with_previous=False, row=line)  # fmt: skip


def test_the_ranking_figure_resolves_the_top_agents_and_names_those_it_leaves_out():
    rows = [_row("a", 1, 1.0, 1.0, 1.0), _row("b", 2, 0.995, 0.99, 0.999),
            _row("c", 3, 0.94, 0.93, 0.96), _row("d", 4, 0.15, 0.13, 0.18),
            _row("e", 5, 0.01, 0.0, 0.02), _row("f", 6, 0.0, 0.0, 0.0, (6, 7)),
            _row("g", 7, 0.0, 0.0, 0.0, (6, 7))]  # fmt: skip
    panels, floor = plots.ranking_layout(rows)
    assert [[r.agent for r in p] for p in panels] == [["a", "b", "c"], ["d", "e"]]
    assert [r.agent for r in floor] == ["f", "g"]
    top, bottom = (plots.panel_limits(p) for p in panels)
    assert 0.88 < top[0] < 0.93 and 1.0 < top[1] < 1.01  # a 1% difference is a visible distance
    assert bottom[0] < 0.0 < 0.18 < bottom[1] < 0.2
    assert plots.not_drawn_note(floor) == (
        "Not drawn: capture rate 0 on every ranked scenario, interval [0, 0]: 6. f [6–7], "
        "7. g [6–7]."
    )
    close = [_row("a", 1, 0.9, 0.85, 0.95), _row("b", 2, 0.6, 0.5, 0.7)]
    assert plots.ranking_layout(close) == ([close], [])  # no gap worth a second axis
    alone = plots.panel_limits([_row("a", 1, 1.0, 1.0, 1.0)])
    assert alone[1] - alone[0] >= plots.MIN_PANEL_SPAN and alone[1] < 1.01
    png = plots.ranking_figure(rows, {r.agent: "#000000" for r in rows})
    assert _png_size(png)[1] > 0


def test_every_figure_has_a_caption_saying_what_it_shows():
    data = _report(12)
    file_name = re.compile(r"^[\w.-]+\.(png|gif)$")
    for name in figure_names(data):
        text = figure_text(data, name)
        assert text.alt and not file_name.match(text.alt) and name not in text.alt
        assert text.caption.startswith(text.alt) and len(text.caption) > len(text.alt) + 40
    ranking = figure_text(data, "summary_ranking.png").caption
    assert "Not drawn: capture rate 0" in ranking  # the two agents that never capture
    with pytest.raises(ValueError, match="no figure named 'nothing.png'"):
        figure_text(data, "nothing.png")


def test_the_scenario_tables_follow_the_ranking_in_both_pages():
    data = _report(6)
    order = [r.agent for r in data.ranking]
    assert [s.agent for s in data.summaries if s.scenario == "s1"] != order  # records reversed
    for scenario in SCENARIOS:
        assert [s.agent for s in scenario_summaries(data, scenario)] == order
    md = markdown(data, (None, "not needed"))
    for scenario in SCENARIOS:
        section = md[md.index(f"\n## {scenario}\n") :]
        for header in (MAIN_HEADER, DETAIL_HEADER):
            table = section[section.index("| " + " | ".join(header)) :].split("\n\n")[0]
            agents = [line.split(" | ")[0][2:] for line in table.splitlines()[2:]]
            assert [a.removesuffix(" (reference)") for a in agents] == order
    images = {name: b"\x89PNG" for name in figure_names(data)}
    page = html_page(data, images, (None, "not needed"))
    for scenario in SCENARIOS:
        section = page[page.index(f'<section id="scenario-{scenario}">') :]
        section = section[: section.index("</section>")]
        cells = re.findall(r"<tr><td>([^<]*)</td>", section)
        main, detail = cells[: len(order)], cells[len(order) :]
        assert [a.removesuffix(" (reference)") for a in main] == order and detail == order


def test_both_pages_open_with_the_capture_rule_what_the_limit_is_and_the_ranking():
    data = _report(3)
    md = markdown(data, (None, "not needed")).splitlines()
    assert md[2] == report_capture_rule(data) and md[4] == READING
    assert "1.00x is as fast as physically possible, 1.13x is 13% slower" in READING
    assert md.index("## Overall ranking") < md.index("## Summary")
    page = html_page(data, {n: b"\x89PNG" for n in figure_names(data)}, (None, "not needed"))
    assert '<meta name="viewport" content="width=device-width, initial-scale=1">' in page
    head = page[: page.index("<h2>")]
    for anchor in re.findall(r'href="#([^"]+)"', head):
        assert f'id="{anchor}"' in page
    assert page.index('id="ranking"') < page.index('id="summary"') < page.index('id="scenarios"')
    for image in re.findall(r"<img [^>]*>", page):
        assert 'alt="' in image and not re.search(r'alt="[\w.-]+\.png"', image)
    shown = len(figure_names(data)) - 1  # the rliable section's profile: no numbers here
    assert page.count("<img ") == page.count("<figcaption>") == shown


def test_the_figures_are_the_same_bytes_however_they_are_split():
    data = _report(4)
    whole = figures(data)
    assert whole == figures(data)
    split: dict = {}
    for group in figure_groups(data, 3):
        split.update(figures(data, group))
    assert split == whole


def test_the_learning_curves_page_renders_code_spans_and_fits_a_phone():
    from capture_bench.training.curves.command import _html

    page = _html(
        "# Learning curves on `paper`\n\nThe dashed line is `incremental_ik`.\n\n"
        "### A `third` level\n\n| a | b |\n|---|---|\n| `x` | 1 |\n\n- command: `run it`\n"
        "- runs: `runs`\n",
        {},
    )
    assert "`" not in page
    assert "<h1>Learning curves on <code>paper</code></h1>" in page
    assert "<p>The dashed line is <code>incremental_ik</code>.</p>" in page
    assert "<h3>A <code>third</code> level</h3>" in page
    assert '<div class="scroll"><table><tr><th>a</th><th>b</th></tr>' in page
    assert "<tr><td><code>x</code></td><td>1</td></tr></table></div>" in page
    assert "<ul><li>command: <code>run it</code></li><li>runs: <code>runs</code></li></ul>" in page
    assert 'name="viewport"' in page


def test_the_committed_learning_curves_pages_are_what_the_code_makes_of_their_markdown():
    from pathlib import Path

    from capture_bench.training.curves.command import _html

    root = Path(__file__).parents[1]
    pages = sorted(root.glob("docs/results/*/learning_curves.html"))
    pages += [root / "reports" / "learning_curves" / "learning_curves.html"]
    for page in pages:
        folder = page.parent
        images = {p.name: p.read_bytes() for p in folder.glob("*.png")}
        made = _html((folder / "learning_curves.md").read_text(), images)
        assert page.read_text() == made, f"{page.relative_to(root)} is not its markdown's page"
