"""Every committed study under results/ regenerates its committed report from its result files alone."""

from __future__ import annotations

import html
import json
import shutil
from pathlib import Path

import pytest

from bcbench.analysis.report import write_report

RESULTS = Path(__file__).resolve().parents[1] / "results"
STUDIES = sorted(p.parent.parent for p in RESULTS.glob("*/report/report.md"))


def test_there_is_committed_evidence():
    assert STUDIES, "no committed study report under results/"


@pytest.mark.parametrize("study", STUDIES, ids=[p.name for p in STUDIES])
def test_committed_report_regenerates_identically(study, tmp_path):
    """A fresh copy (as in a clone: no checkpoints, no runs/) rebuilds the same Markdown report."""
    copy = tmp_path / study.name
    shutil.copytree(study, copy, ignore=shutil.ignore_patterns("report"))
    combine, across = study / "combine.json", study / "across.json"  # the folders these name come along, as in a
    named = json.loads(combine.read_text())["studies"] if combine.exists() else []  # clone
    if across.exists():  # a report across tasks: each task's folder (and its own studies) and the records
        spec = json.loads(across.read_text())
        named = [*spec["tasks"], *([spec["demos"]] if "demos" in spec else []), *spec.get("more_demos", {}).values(),
                 *spec.get("larger_frame", {}).values()]
        named += [str(Path(t) / s) for t in spec["tasks"] if (study / t / "combine.json").exists()
                  for s in json.loads((study / t / "combine.json").read_text())["studies"]]
    for name in named:
        if not (copy / name).resolve().exists():
            shutil.copytree((study / name).resolve(), (copy / name).resolve(), ignore=shutil.ignore_patterns("report"))
    assert not list(copy.rglob("*.safetensors"))  # result files only
    paths = write_report(copy)
    assert Path(paths["markdown"]).read_text() == (study / "report" / "report.md").read_text()
    choose = [x for x in Path(paths["markdown"]).read_text().splitlines() if "| median ms, batch 1 (fastest" in x]
    if choose:  # the regenerated HTML heads its choice table as the regenerated Markdown does
        cells = "".join(f"<th>{html.escape(c.strip())}</th>" for c in choose[0].strip("|").split("|"))
        assert f"<thead><tr>{cells}</tr></thead>" in Path(paths["html"]).read_text()
    for png in (study / "report").glob("*.png"):
        assert (copy / "report" / png.name).stat().st_size > 1000  # every committed figure is redrawn


DOCS = [RESULTS.parent / "README.md", *sorted((RESULTS.parent / "docs").glob("*.md")),
        *sorted(RESULTS.glob("**/README.md")), *sorted((RESULTS.parent / "models").glob("*/README.md"))]


def test_every_relative_link_in_the_docs_points_to_a_committed_file():
    """A README figure or link that names a moved or never-committed file is a number without its file."""
    import re

    broken = []
    for doc in DOCS:
        for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):  # web addresses and anchors
                continue
            if not (doc.parent / target.split("#")[0]).exists():
                broken.append(f"{doc.relative_to(RESULTS.parent)}: {target}")
    assert len(DOCS) > 10 and not broken, broken


WALLCLOCK = sorted(p.parent for p in RESULTS.glob("**/comparison.json") if (p.parent / "wallclock.json").exists())


@pytest.mark.parametrize("run", WALLCLOCK, ids=[f"{p.parent.name}/{p.name}" for p in WALLCLOCK])
def test_committed_wallclock_comparison_regenerates(run):
    """A committed wall-clock comparison is what its two records give: scores, paired interval and delays."""
    from bcbench.analysis.wallclock import compare_files

    committed = json.loads((run / "comparison.json").read_text())
    (twin,) = run.glob("simulated-async-d*.json")  # the twin the run itself wrote, at the rule's d
    assert f"-d{committed['d']}.json" in twin.name
    regenerated = json.loads(json.dumps(compare_files(str(run / "wallclock.json"), str(twin))))
    assert regenerated == committed  # the bootstrap's seed is fixed: the same file, number for number


def test_the_delay_trained_sweep_readme_numbers_come_from_its_records():
    """results/realtime-delay-sweeps/README.md states each prefix score and its paired interval against the plain
    seed-0 model's sync; both are recomputed here from the committed records."""
    from bcbench.analysis.realtime import replicate_scores
    from bcbench.stats import paired_bootstrap

    folder, plain = RESULTS / "realtime-delay-sweeps", RESULTS / "strategies-replicates/dp-ddim10/seed0"
    readme = (folder / "README.md").read_text()
    (sync,) = replicate_scores(str(plain / "naive-d4/realtime-sync.json"))
    for d in (4, 8):
        (prefix,) = replicate_scores(str(folder / f"dp-s0/prefix/realtime-async-d{d}.json"))
        record = json.loads((folder / f"dp-s0/prefix/realtime-async-d{d}.json").read_text())
        assert record["policy"]["config"]["delay_train"] == [0, 8] and record["eval_config"]["strategy"]["strategy"] \
            == "prefix" and len(prefix) == 100
        diff, lo, hi, _ = paired_bootstrap(prefix, [sync])
        assert f"{sum(prefix.values()) / 100:.3f} ({diff:+.3f} [{lo:+.3f}, {hi:+.3f}])" in readme, d


def test_a_report_rebuilt_in_place_drops_a_figure_it_no_longer_draws(tmp_path):
    copy = tmp_path / "study"
    shutil.copytree(RESULTS / "metaworld-explore-3", copy)  # no real-time sweep: no realtime.png to draw
    stale = copy / "report" / "realtime.png"
    stale.write_bytes(b"an earlier drawing")
    write_report(copy)
    assert not stale.exists()
    for png in (RESULTS / "metaworld-explore-3" / "report").glob("*.png"):
        assert (copy / "report" / png.name).stat().st_size > 1000  # what it draws stays
