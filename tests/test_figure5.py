"""Figure 5 where the generative settings crowd: a zoom that names them, labels that overlap nothing, one colour per
configuration, and the settings that share an interleaved timing named."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import matplotlib.pyplot as plt
import pytest

from bcbench.analysis.accuracy_latency import Panel, figure5, place_labels, zoom_box
from bcbench.analysis.figures import budgets, row_budgets
from bcbench.analysis.findings import shared_timing


@dataclass
class _Row:
    """What Figure 5 reads of a result row."""

    label: str
    policy: str
    variant: str
    score: float
    ms: float
    params: int = 5_330_000
    summary: dict = field(default_factory=dict)
    control_hz: float = 10.0  # Push-T's rate and horizon unless a test says otherwise
    action_horizon: int | None = 8
    train_seed: int | None = 0

    @property
    def key(self) -> str:
        return f"{self.label}:{self.variant}"

    @property
    def reference_key(self) -> str:
        return self.policy

    def est(self, name: str) -> dict:
        return {"value": self.score, "ci95": [self.score - 0.05, self.score + 0.05]}

    def latency_ms(self, mode: str) -> float:
        return self.ms

    def deployed_ms(self) -> tuple[str, float]:
        return ("openvino-fp32", self.ms / 2.4)


def _crowd() -> list[_Row]:
    """Two DP configurations at 15 settings each and flow at 5, within 0.2 of score and a decade of time, like the
    confirm report's; one DP setting far below (DDIM-1 of the cosine model), and two small policies."""
    rows = []
    for label, shift in (("DP cosine", 0.0), ("DP linear", -0.02)):
        for i, (sampler, steps) in enumerate(itertools.product(("ddpm", "ddim"), (1, 2, 5, 10, 20, 50, 100, 4))):
            if (sampler, steps) == ("ddpm", 4):
                continue
            score = 0.09 if (label, steps) == ("DP cosine", 1) else 0.70 + 0.15 * (i % 7) / 6 + shift
            rows.append(_Row(label, "diffusion", f"{sampler}{steps}", score, 6.0 * steps + 5))
    rows += [_Row("flow", "flow", f"euler{k}", 0.82 + 0.01 * k, 6.0 * k + 4) for k in (1, 2, 4, 10)]
    return [*rows, _Row("BCT", "bct", "default", 0.56, 6.1), _Row("scripted", "scripted", "default", 0.56, 0.4)]


def test_crowded_generative_settings_get_a_zoom_and_its_labels_overlap_nothing(tmp_path):
    rows = _crowd()
    panel = Panel(rows, {r.key: r.ms for r in rows}, "reference", None)
    inside, (x0, x1, y0, y1) = zoom_box(panel)
    assert "DP cosine:ddim1" not in {r.key for r in inside} and len(inside) == 32  # far below the best: not zoomed
    assert not any(r.variant == "default" for r in inside)  # the small policies are not named
    assert x0 <= min(r.ms / 2.4 for r in inside) and x1 > max(r.ms for r in inside)  # the arrows' tips fit
    fig, ax = plt.subplots(figsize=(12, 6.5))
    _, markers = panel.draw(ax)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    labels = place_labels(ax, [panel.label(r) for r in inside], fontsize=7, markers=markers)
    renderer = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(renderer).expanded(1, 1).padded(-0.5) for t in labels]  # touching is not over
    assert len(boxes) == 32
    pairs = itertools.combinations(zip(labels, boxes, strict=True), 2)
    clashes = [(a.get_text(), b.get_text()) for (a, p), (b, q) in pairs if p.overlaps(q)]
    assert not clashes
    # a label takes its point's colour: the linear model's DDPM5 is told from the cosine model's
    tints = {(t.get_text(), t.get_color()) for t in labels}
    assert ("DDPM5", "tab:red") in tints and ("DDPM5", "tab:cyan") in tints
    plt.close(fig)
    main, zoom = figure5(rows, tmp_path / "fig5.png", zoom_path=tmp_path / "zoom.png")
    assert main.stat().st_size > 1000 and zoom.stat().st_size > 1000


def test_few_generative_settings_stay_in_one_panel(tmp_path):
    rows = [r for r in _crowd() if r.label != "DP linear" and r.variant in ("default", "ddim10", "ddpm100", "euler2")]
    assert zoom_box(Panel(rows, {r.key: r.ms for r in rows}, "reference", None)) is None
    main, zoom = figure5(rows, tmp_path / "fig5.png", zoom_path=tmp_path / "zoom.png")
    assert main.exists() and zoom is None and not (tmp_path / "zoom.png").exists()


@pytest.mark.parametrize("timed", [{"ddim10": 25.9, "ddpm100": 256.7}, {"ddim10": 25.9}])
def test_configurations_that_share_an_interleaved_timing_are_named(timed):
    rows = _crowd()
    assert shared_timing(rows, {"median_ms": timed}) == ["DP cosine", "DP linear"]
    assert shared_timing(rows, {"median_ms": {"euler2": 9.0}}) == []  # one flow configuration: nothing shared
    assert shared_timing(rows, None) == []


def test_the_budget_lines_are_the_tasks_rate_and_the_runs_horizons():
    """Figure 5's dashed lines: one control step at the task's rate and one chunk of each trained run's executed
    steps. Push-T's 100 and 800 ms are not MetaWorld's (80 Hz, 3 executed: 12.5 and 37.5 ms)."""
    assert budgets() == ((100.0, "10 Hz, re-plan every step (100 ms)"),
                         (800.0, "10 Hz, re-plan every 8 steps (800 ms)"))
    meta = [_Row("DP", "diffusion", "ddim10", 0.13, 60.0, control_hz=80.0, action_horizon=3),
            _Row("BCT", "bct", "default", 0.24, 8.0, control_hz=80.0, action_horizon=3),
            # a baseline's configured horizon was never trained to execute: it draws no line
            _Row("random", "random", "default", 0.0, 0.01, control_hz=80.0, action_horizon=8, train_seed=None)]
    assert row_budgets(meta) == ((12.5, "80 Hz, re-plan every step (12.5 ms)"),
                                 (37.5, "80 Hz, re-plan every 3 steps (37.5 ms)"))
    assert [ms for ms, _ in row_budgets([*meta, _Row("flow", "flow", "euler2", 0.1, 6.0, control_hz=80.0,
                                                         action_horizon=8)])] == [12.5, 37.5, 100.0]
    assert row_budgets([meta[2]]) == budgets(80.0, [8])  # baselines only: their horizon
    assert row_budgets([meta[0], _Row("CNN", "cnn_mlp", "default", 0.5, 4.0)]) == ()  # two rates: no one task's lines
    fig, ax = plt.subplots()
    Panel(meta, {r.key: r.ms for r in meta}, "reference", None).draw(ax)
    assert sorted(line.get_xdata()[0] for line in ax.lines if line.get_linestyle() == "--") == [12.5, 37.5]
    plt.close(fig)


@pytest.mark.parametrize("task, word", [("pusht", "mean score"), ("metaworld/pick-place", "success rate")])
def test_a_score_axis_names_what_its_task_scores(task, word, monkeypatch, tmp_path):
    """Push-T's score is a coverage; a MetaWorld task's is success (1/0), so its axes say success rate."""
    import bcbench.analysis.figures as figures

    @dataclass
    class _Step(_Row):
        sampler: str = "ddim"
        steps: int = 10
        beta_schedule: str | None = None
        spacing: str | None = "trailing"
        task: str = "pusht"

    rows = [_Step("DP", "diffusion", f"ddim{k}", 0.5, 6.0 * k, steps=k, task=task) for k in (2, 10)]
    drawn = []
    monkeypatch.setattr(figures, "save_png", lambda fig, path: drawn.append(fig) or path)
    figures.figure3(rows, tmp_path / "fig3.png")
    assert figures.score_word(rows) == word and drawn[0].axes[0].get_ylabel() == f"{word} (95% CI)"
    plt.close("all")
