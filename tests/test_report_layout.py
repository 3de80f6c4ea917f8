"""The committed HTML reports as a reader sees them, in headless Chromium (scripts/check_report.py): Figure 5 and
the "which policy" table in a laptop's first screen, no sideways scrolling, every figure decoded.

Runs where Chromium is installed (`apt-get install chromium`; `.ci/run` installs it where it can); skipped elsewhere."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
REPORTS = sorted((ROOT / "results").glob("*/report/report.html"))
_spec = importlib.util.spec_from_file_location("check_report", ROOT / "scripts" / "check_report.py")
check = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(check)
EXE = check.chromium()
needs_chromium = pytest.mark.skipif(EXE is None, reason="no Chromium on this machine")


@needs_chromium
@pytest.mark.parametrize("report", REPORTS, ids=[p.parent.parent.name for p in REPORTS])
def test_committed_report_reads_in_one_screen(report):
    m = check.layout(EXE, report)
    across = (report.parent.parent / "across.json").exists()  # its figures are each task's, drawn where timed
    assert (m["figures"] or across) and not check.problems(m), check.problems(m)


@needs_chromium
def test_the_check_sees_a_table_below_the_fold_and_a_page_too_wide(tmp_path):
    page = tmp_path / "report.html"
    page.write_text("<!doctype html><html><body><div style='height:2000px'></div><div style='width:3000px'>x</div>"
                    "<table><tr><td>policy</td></tr></table></body></html>")
    found = check.problems(check.layout(EXE, page))
    assert any("below the first screen" in p for p in found) and any("sideways" in p for p in found), found


@pytest.mark.parametrize("study, untimed", [("cpu-confirm-dpflow", True), ("cpu-confirm-dpflow-long", False),
                                            ("cpu", False)])
def test_figure3_says_when_nothing_is_timed_rather_than_draw_empty_axes(study, untimed, tmp_path, monkeypatch):
    """A study with no latency stages (the first confirm round) gets a note in the latency panel; a timed one
    (results/cpu, the second round once its timing stages ran) gets its lines and no note."""
    from bcbench.analysis import figures
    from bcbench.analysis.results import load_rows
    from bcbench.analysis.seeds import merge_training_seeds

    drawn = []
    monkeypatch.setattr(figures, "save_png", lambda fig, path: drawn.append(fig) or path)
    root = Path(__file__).resolve().parents[1] / "results" / study
    assert figures.figure3(merge_training_seeds(load_rows(root)), tmp_path / "f.png") is not None
    latency_panel = drawn[0].axes[1]
    notes = [t.get_text() for t in latency_panel.texts]
    assert (notes == ["not timed yet\n(no reference-mode latency record)"]) == untimed
    assert bool(latency_panel.lines) != untimed


def test_figure_5_gives_up_height_to_a_longer_table_or_introduction():
    """A report with more policies (more rows in the choice table) or a longer introduction (a combined report names
    every machine), rows that wrap (long names with their sizes) or a sentence under the table shrinks Figure 5 so
    that the table still ends in the first screen, never below 18% of it."""
    from bcbench.analysis.report import ROW_PX, _lead_height

    row = ["policy", "setting", "score"]  # one line
    assert _lead_height("x" * 300, [row] * 4) == ""  # the class's 46vh
    # each row past 4 at its measured height (drawer-open's 7-row table ended 29 px below the first screen at 24 px)
    assert _lead_height("x" * 300, [row] * 8) == f"max-height:max(18vh, calc(46vh - {4 * ROW_PX}px))"
    assert _lead_height("x" * 700, [row] * 4) == "max-height:max(18vh, calc(46vh - 44px))"  # 5 lines of 170 characters
    assert _lead_height("x" * 300, [row] * 3 + [["y" * 200]]) == "max-height:max(18vh, calc(46vh - 18px))"  # 2 lines
    assert _lead_height("x" * 300, [row] * 4, "z" * 100) == "max-height:max(18vh, calc(46vh - 22px))"  # a sentence


@pytest.mark.parametrize("report", REPORTS, ids=[p.parent.parent.name for p in REPORTS])
def test_every_committed_report_embeds_its_figures(report):
    """A figure linked by a relative path vanishes when the page is read from a copy (the layout check reads one, so
    does a mail or a reviewer's download): every <img> carries its PNG as a data URI. Runs without Chromium."""
    sources = re.findall(r"<img [^>]*src='([^']*)'", report.read_text())
    assert all(s.startswith("data:image/png;base64,") for s in sources), [s[:60] for s in sources]


@pytest.mark.parametrize("report", [p for p in REPORTS if not (p.parent.parent / "across.json").exists()],
                         ids=lambda p: p.parent.parent.name)
def test_the_html_choice_table_has_the_markdowns_header(report):
    """The HTML's choice table is headed as the Markdown's, with the task's own step rate (a MetaWorld report once
    printed Push-T's 10 Hz there)."""
    import html

    md = (report.parent / "report.md").read_text()
    header = next((line for line in md.splitlines() if line.startswith("| policy | setting | score [95% CI] |")), None)
    if header is None:
        pytest.skip("no choice table")
    cells = [c.strip() for c in header.strip("|").split("|")]
    assert "<thead><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in cells) + "</tr></thead>" in report.read_text()
