"""Execution under latency: sync, blocking and async controllers, latency sources, and their errors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from bcbench.errors import BCBenchError
from bcbench.evaluation.controller import ChunkedController
from bcbench.evaluation.evaluate import EvalConfig, evaluate
from bcbench.evaluation.latency_sources import LatencySource, profile_ms, steps_for
from bcbench.policies import make_policy


class PlannedStep:
    """Chunk entry j of a call made at step t is the action (t + j, call index): it says when it was meant for."""

    name = "planned-step"
    obs_horizon, pred_horizon, action_horizon, chunk_start = 2, 16, 8, 0

    def __init__(self) -> None:
        self.calls = 0

    def predict_action_chunk(self, obs):
        t = obs["agent_pos"][:, -1, 0]  # the newest observation carries its step
        chunk = np.stack([t[:, None] + np.arange(16), np.full((len(t), 16), self.calls)], axis=-1)
        self.calls += 1
        return chunk.astype(np.float32)


def _run(execution: str, d: int, steps: int = 24, s: int | None = None) -> list[tuple[float, float]]:
    ctl = ChunkedController(PlannedStep(), execution=execution, delay=lambda env_id: d, execution_horizon=s)
    obs = lambda t: {"pixels": np.zeros((96, 96, 3), np.uint8), "agent_pos": np.array([t, -1.0])}  # noqa: E731
    ctl.reset(0, obs(0))
    out = []
    for t in range(steps):
        out.append(tuple(float(v) for v in ctl.act([0])[0]))
        ctl.observe(0, obs(t + 1))
    return out


@pytest.mark.parametrize("execution", ["blocking", "async"])
def test_zero_delay_is_sync(execution):
    assert _run(execution, 0) == _run("sync", 0)


def test_async_skips_the_past_and_uses_the_old_chunks_leftovers():
    acts = _run("async", 3)
    assert acts[:3] == [(0.0, -1.0)] * 3  # nothing planned yet: hold the start position
    for t in range(3, 24):
        assert acts[t][0] == t  # every action executed at step t is the one planned for step t
    # call 1 is made at step 5 (3 actions left) from step 5's observation; steps 5-7 still run call 0's chunk
    assert [a[1] for a in acts[3:9]] == [0, 0, 0, 0, 0, 1]


def test_the_execution_horizon_runs_s_actions_of_every_chunk():
    """Diffusion Policy's latency protocol (its Fig. 6): the first d actions dropped, then 8 executed (s = 8)."""
    acts = _run("async", 3, steps=60, s=8)
    assert all(acts[t][0] == t for t in range(3, 60))  # still the action planned for each step
    calls = [int(a[1]) for a in acts[3:]]
    runs = [len(list(g)) for _, g in itertools.groupby(calls)]
    assert runs[:-1] == [8] * (len(runs) - 1)  # 8 steps of each chunk, the last one cut by the episode's end
    for d in (1, 2, 3):  # the default is s = action horizon - d: today's async, unchanged
        assert _run("async", d, steps=40, s=8 - d) == _run("async", d, steps=40)


def test_the_execution_horizon_must_fit_in_the_chunk_and_goes_with_async():
    with pytest.raises(BCBenchError, match=r"needs 17 actions of a chunk of 16 \(s <= H - d"):
        _run("async", 3, s=14)
    with pytest.raises(BCBenchError, match="goes with --execution async"):
        EvalConfig(execution="blocking", execution_horizon=8)


def test_blocking_holds_the_last_target_while_computing():
    acts = _run("blocking", 3)
    assert acts[:3] == [(0.0, -1.0)] * 3  # call 0 (step 0) arrives at step 3
    assert [a[0] for a in acts[3:11]] == list(range(8))  # its chunk from its start: planned 3 steps ago
    assert acts[11:14] == [acts[10]] * 3  # call 1 (step 11) computes: the last target is held
    assert acts[14] == (11.0, 1.0)


def test_async_delay_must_leave_something_of_the_chunk():
    with pytest.raises(BCBenchError, match="entirely in the past"):
        _run("async", 16)


def test_rtc_horizon_note_says_which_horizon_keeps_s_at_least_d_or_that_none_can():
    from bcbench.evaluation.realtime import rtc_horizon_note

    policy = PlannedStep()
    policy.chunk_start = 1  # as the learned policies: the current step's action is index 1 of 16
    assert rtc_horizon_note(policy, [1, 2, 4], None) is None  # default s = 8 - d >= d up to d = 4
    note = rtc_horizon_note(policy, [4, 6, 8], None)
    assert "d = 6, 8 executes fewer" in note and "6 <= s <= 9 keeps it at d = 6" in note
    assert "at d = 8 no horizon does (d + s <= 15" in note and "d = 4" not in note.split(":")[1]
    assert rtc_horizon_note(policy, [8], 7).endswith("at d = 8 no horizon does (d + s <= 15 with this chunk)")
    assert rtc_horizon_note(policy, [6], 7) is None


def test_realtime_evaluation_is_deterministic_and_records_its_delays():
    cfg = EvalConfig(episodes=3, max_steps=40, workers=1, execution="async", latency_ms=250)
    a = evaluate(make_policy("scripted"), cfg, None, progress=False)
    b = evaluate(make_policy("scripted"), cfg, None, progress=False)
    assert [e["score"] for e in a["episodes"]] == [e["score"] for e in b["episodes"]]
    s = a["summary"]
    assert s["execution"] == "async" and s["latency_source"] == {"kind": "fixed", "ms": 250.0}
    assert set(s["delay_steps"]) == {"3"}
    sync = evaluate(make_policy("scripted"), EvalConfig(episodes=3, max_steps=40, workers=1), None, progress=False)
    assert [e["final_state"] for e in sync["episodes"]] != [e["final_state"] for e in a["episodes"]]


def test_latency_sources():
    assert steps_for(0.0) == 0 and steps_for(0.1) == 1 and steps_for(0.25) == 3 and steps_for(0.1001) == 2
    assert profile_ms("a100", "cnn_mlp") == 2.2
    assert profile_ms("a100", "diffusion", 10) == pytest.approx(116.5)
    assert profile_ms("a100", "diffusion", 100) == pytest.approx(1109.4)
    src = LatencySource("measured", samples_ms=[50.0, 150.0, 350.0])
    f, g = src.delay_fn({0: 100000}), src.delay_fn({0: 100000})
    draws = [f(0) for _ in range(50)]
    assert draws == [g(0) for _ in range(50)] and set(draws) == {1, 2, 4}  # seeded per episode, from the samples


@pytest.mark.parametrize("args, message", [
    (["--latency-ms", "-5"], "must be >= 0"),
    (["--latency", "profile:tpu"], "unknown latency profile 'tpu'"),
    (["--latency", "soon"], "must be 'measured' or 'profile:NAME'"),
    (["--latency-ms", "1700", "--execution", "async"], "entirely in the past"),
])
def test_bad_realtime_input_is_one_line_exit_2(args, message, capsys):
    from bcbench.cli.main import main

    assert main(["eval", "--policy", "scripted", "--episodes", "1", "--max-steps", "5", "--quiet", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_realtime_sweep_cli(tmp_path, capsys):
    from bcbench.cli.main import main

    out = tmp_path / "rt"
    assert main(["realtime", "--policy", "scripted", "--episodes", "2", "--delays", "0", "2", "--profile", "a100",
                 "--out", str(out), "--quiet"]) == 2  # the a100 profile has no time for the scripted baseline
    assert "no inference time for 'scripted'" in capsys.readouterr().err
    assert main(["realtime", "--policy", "scripted", "--episodes", "2", "--delays", "0", "2", "--out", str(out),
                 "--max-steps", "30", "--quiet"]) == 0
    names = sorted(p.name for p in out.glob("realtime-*.json") if p.name != "realtime-sweep.json")
    assert names == ["realtime-async-d2.json", "realtime-blocking-d2.json", "realtime-sync.json"]
    assert (out / "realtime.png").stat().st_size > 1000
    printed = capsys.readouterr().out
    assert "realtime-async-d2" in printed and "too few episodes to decide (2)" in printed  # no verdict from 2
    assert not (out / "fig5_realtime.png").exists()  # no measured setting: no real-time Figure 5
    from bcbench.analysis.results import load_realtime

    found = load_realtime(tmp_path)  # the sweep's record: what a study's report reads when it lies inside one
    assert list(found) == ["scripted"] and sorted(found["scripted"]) == [n.removesuffix(".json") for n in names]


def _setting(scores: np.ndarray, median_ms: float | None = None) -> dict:
    summary = {"mean_score": {"value": float(scores.mean()), "ci95": [float(scores.mean()) - 0.05,
                                                                      float(scores.mean()) + 0.05]}}
    if median_ms is not None:
        summary["latency_source"] = {"kind": "measured", "calls": 100, "median_ms": median_ms, "max_ms": 2 * median_ms}
    return {"episodes": [{"seed": 100_000 + i, "score": float(s)} for i, s in enumerate(scores)], "summary": summary}


def test_realtime_report_states_the_largest_safe_delay_and_the_highest_safe_rate(tmp_path):
    """A policy unhurt up to d = 2 at 50 ms a call is safe up to 2 / 0.05 s = 40 Hz (20 Hz at its slowest
    call, 100 ms); one that loses 0.3 at d = 1 has no safe real-time rate; one that keeps its score blocking
    but not async gets the blocking rate. Figure 5, real time, is drawn."""
    from bcbench.analysis.figures import figure5_realtime
    from bcbench.analysis.realtime import highest_safe_rate
    from bcbench.analysis.report import realtime_lines

    base = np.random.default_rng(0).uniform(0.3, 0.9, 100)
    steady = {"realtime-sync": _setting(base), "realtime-async-d1": _setting(base), "realtime-async-d2":
              _setting(base - 0.01), "realtime-async-d4": _setting(base - 0.3),
              "realtime-async-measured": _setting(base, median_ms=50.0)}
    fragile = {"realtime-sync": _setting(base), "realtime-async-d1": _setting(base - 0.3),
               "realtime-async-measured": _setting(base - 0.3, median_ms=500.0)}
    # async loses at d = 1 but blocking holds it: the rate comes from the mode that keeps the score
    mixed = {"realtime-sync": _setting(base), "realtime-async-d1": _setting(base - 0.3),
             "realtime-blocking-d1": _setting(base), "realtime-blocking-d2": _setting(base - 0.3),
             "realtime-blocking-measured": _setting(base, median_ms=50.0)}
    backend = {"realtime-sync": _setting(base), "realtime-async-measured": _setting(base - 0.1, median_ms=20.0)}
    no_d1 = {"realtime-sync": _setting(base), "realtime-async-d2": _setting(base - 0.2)}  # a sweep from d = 2
    lines = "\n".join(realtime_lines({"steady": steady, "fragile": fragile, "mixed": mixed, "backend": backend,
                                      "no_d1": no_d1}, 0.05))
    assert "(d = 2 minus sync: async -0.200 [-0.200, -0.200])" in lines
    assert "At its measured latency, minus sync: async -0.100 [-0.100, -0.100]." in lines  # no delay settings
    m = float(base.mean())  # the table: one row per policy, "-" where a setting was not run
    assert f"| backend | {m:.3f} | - | - | - | - | - | - | - | - | {m - 0.1:.3f} (20 ms) | - | - |" in lines
    # 20 and 40 Hz capped at the 10 Hz step rate the sweep counts delay in
    assert ("async d = 0, blocking d = 1; its measured median call 50 ms fits within blocking d = 1 at 10 Hz; "
            "highest safe control rate 10.0 Hz (10.0 Hz at its slowest call), blocking (capped at Push-T's 10 Hz step "
            "rate, in which the sweep counts delay: the calls alone would allow 20 Hz, 10 Hz at the slowest).") in lines
    assert ("async d = 2; its measured median call 50 ms fits within async d = 2 at 10 Hz; highest safe control "
            "rate 10.0 Hz (10.0 Hz at its slowest call), async (capped at Push-T's 10 Hz step rate, in which the sweep "
            "counts delay: the calls alone would allow 40 Hz, 20 Hz at the slowest).") in lines
    assert "async d = 0: no delay is shown within the margin (d = 1 minus sync: async -0.300 [-0.300, -0.300])" \
           ", so no real-time control rate" in lines
    assert highest_safe_rate(None, 50.0) is None
    path = figure5_realtime({"steady": steady, "fragile": fragile}, tmp_path / "fig5_realtime.png")
    assert path is not None and path.stat().st_size > 1000
    assert figure5_realtime({"steady": {"realtime-sync": steady["realtime-sync"]}}, tmp_path / "x.png") is None


def test_an_interrupted_sweep_keeps_its_finished_settings(monkeypatch):
    """A study's sweep saves after every setting; rerun with what was saved, it evaluates only the rest."""
    import bcbench.evaluation.realtime
    from bcbench.evaluation.realtime import sweep

    real, ran, saved = bcbench.evaluation.realtime.evaluate, [], []

    def counting(policy, cfg, *args, **kw):
        ran.append(kw["extra"]["realtime"]["setting"])
        return real(policy, cfg, *args, **kw)

    monkeypatch.setattr(bcbench.evaluation.realtime, "evaluate", counting)
    kw = {"delays": [2], "executions": ["async", "blocking"], "episodes": 1, "profiles": [], "measured": False,
          "progress": False, "max_steps": 20}
    full = sweep(make_policy("scripted"), **kw, on_setting=lambda r: saved.append(dict(r)))
    assert ran == ["realtime-sync", "realtime-async-d2", "realtime-blocking-d2"] and len(saved) == 3
    ran.clear()
    resumed = sweep(make_policy("scripted"), **kw, done=saved[1])  # interrupted after two settings
    assert ran == ["realtime-blocking-d2"]
    assert {k: v["summary"]["mean_score"] for k, v in resumed.items()} == \
        {k: v["summary"]["mean_score"] for k, v in full.items()}


def test_a_measured_setting_with_one_delay_is_shown_as_that_fixed_setting():
    from bcbench.analysis.report import same_as_fixed

    def setting(steps):
        return {"summary": {"delay_steps": steps, "mean_score": {"value": 0.5, "ci95": [0.4, 0.6]}}}

    sweep = {"realtime-sync": setting({"0": 10}), "realtime-async-d1": setting({"1": 10}),
             "realtime-async-d2": setting({"2": 10}), "realtime-async-measured": setting({"1": 10}),
             "realtime-blocking-measured": setting({"1": 4, "2": 6})}
    assert same_as_fixed(sweep, "realtime-async-measured") == "async-d1"
    assert same_as_fixed(sweep, "realtime-blocking-measured") is None  # two delays: its own evidence
    assert same_as_fixed(sweep, "realtime-async-d1") is None and same_as_fixed(sweep, "realtime-sync") is None


def test_a_setting_whose_delays_equal_a_fixed_settings_reuses_its_episodes(monkeypatch):
    """A profile (or measured) latency that gives every call the same d repeats that fixed setting's episodes:
    the sweep records them once, says where they come from, and they equal a run of that setting itself."""
    import bcbench.evaluation.realtime
    from bcbench.evaluation.latency_sources import PROFILES
    from bcbench.evaluation.realtime import sweep

    monkeypatch.setitem(PROFILES["a100"], "scripted", 30.0)  # 30 ms: d = 1
    real, ran = bcbench.evaluation.realtime.evaluate, []

    def counting(policy, cfg, *args, **kw):
        ran.append(kw["extra"]["realtime"]["setting"])
        return real(policy, cfg, *args, **kw)

    monkeypatch.setattr(bcbench.evaluation.realtime, "evaluate", counting)
    kw = {"executions": ["async"], "episodes": 2, "profiles": ["a100"], "measured": True, "progress": False,
          "max_steps": 30}
    out = sweep(make_policy("scripted"), delays=[1], **kw)
    assert ran == ["realtime-sync", "realtime-async-d1"]  # the scripted policy's calls are far below 100 ms
    for name in ("realtime-async-a100", "realtime-async-measured"):
        assert out[name]["realtime"] == {"setting": name, "episodes_of": "realtime-async-d1"}
        assert out[name]["summary"]["delay_steps"] == out["realtime-async-d1"]["summary"]["delay_steps"]
    assert out["realtime-async-a100"]["summary"]["latency_source"] == {"kind": "profile", "name": "a100", "ms": 30.0}
    assert out["realtime-async-measured"]["summary"]["latency_source"]["calls"] >= 100
    assert out["realtime-async-a100"]["eval_config"]["latency"] == "profile:a100"
    own = real(make_policy("scripted"), EvalConfig(episodes=2, execution="async", max_steps=30,
                                                    latency="profile:a100"), None, progress=False)
    assert [e["score"] for e in own["episodes"]] == [e["score"] for e in out["realtime-async-a100"]["episodes"]]
    ran.clear()
    out = sweep(make_policy("scripted"), delays=[2], **kw)  # d = 1 not swept: each setting runs its own episodes
    assert ran == ["realtime-sync", "realtime-async-d2", "realtime-async-a100", "realtime-async-measured"]
    assert "episodes_of" not in out["realtime-async-a100"]["realtime"]


def test_sweeps_of_several_training_seeds_are_pooled_over_them(tmp_path):
    """A policy swept once per training seed is one row: each setting's score the mean over the seeds, its delay
    differences paired within a seed and resampling seeds too (two-level), so a seed that alone looks safe does
    not hide one that is not; the report says which sweeps are pooled."""
    from bcbench.analysis.realtime import delay_vs_sync
    from bcbench.analysis.report import realtime_lines
    from bcbench.analysis.results import load_realtime
    from bcbench.stats import over_training_seeds
    from bcbench.utils.io import write_json

    base = np.random.default_rng(1).uniform(0.3, 0.9, 50)
    losses = {0: 0.0, 1: 0.2}  # async d = 1 costs seed 1 a lot, seed 0 nothing
    for seed, loss in losses.items():
        settings = {"realtime-sync": _setting(base + 0.05 * seed),
                    "realtime-async-d1": _setting(base + 0.05 * seed - loss),
                    "realtime-async-measured": _setting(base + 0.05 * seed - loss, median_ms=40.0 + 20 * seed)}
        for r in settings.values():
            r["policy"] = {"config": {"seed": seed}}
        write_json(tmp_path / f"runs/bct-s{seed}/realtime-default.json",
                   {"type": "realtime", "study": {"label": "BCT"}, "settings": settings})
    pooled = load_realtime(tmp_path)
    assert list(pooled) == ["BCT"]
    sync, d1 = pooled["BCT"]["realtime-sync"], pooled["BCT"]["realtime-async-d1"]
    assert sync["summary"]["mean_score"]["value"] == pytest.approx(base.mean() + 0.025)
    assert d1["summary"]["mean_score"]["value"] == pytest.approx(base.mean() + 0.025 - 0.1)
    assert sync["summary"]["training_seeds"] == [0, 1] and sync["summary"]["n"] == 100
    est, lo, hi, pairs = delay_vs_sync(pooled["BCT"], "realtime-async-d1")
    expected = over_training_seeds([{100_000 + i: -loss for i in range(50)} for loss in losses.values()])
    assert (est, [lo, hi], pairs) == (pytest.approx(-0.1), pytest.approx(expected["ci95"]), 100)
    assert lo <= -0.2 + 1e-9 and hi >= -1e-9  # the interval spans both seeds' losses: seed variance is in it
    assert pooled["BCT"]["realtime-async-measured"]["summary"]["latency_source"]["median_ms"] == 50.0
    assert "Swept with several training seeds (BCT: 0, 1)" in "\n".join(realtime_lines(pooled, 0.05))


def test_the_report_says_how_many_episodes_the_margin_needs():
    """With per-episode differences of SD 0.25 and no true loss, 100 episodes give a 95% interval of about
    +/-0.049, as wide as the 0.05 margin; about ((1.96 + 0.84) 0.25 / 0.05)^2 = 197 episodes show such a setting
    within it with 80% power. Settings far outside the margin (a large loss widens the spread) are left out,
    and no number of episodes shows a setting whose true loss is the margin or more."""
    from bcbench.analysis.report import realtime_lines
    from bcbench.stats import episodes_to_show_within

    assert episodes_to_show_within(0.25, 0.05) == pytest.approx(196.2, abs=0.1)
    assert episodes_to_show_within(0.25, 0.05, diff=-0.025) == pytest.approx(4 * 196.2, abs=0.5)
    assert episodes_to_show_within(0.25, 0.05, diff=-0.05) == float("inf")
    base = np.random.default_rng(2).uniform(0.3, 0.9, 100)
    noise = np.tile([0.25, -0.25], 50)  # differences of mean 0 and SD 0.25 (0.2513 with n - 1)
    sweep = {"realtime-sync": _setting(base), "realtime-async-d1": _setting(base + noise),
             "realtime-async-d8": _setting(base - 0.4 + 2 * noise)}
    text = "\n".join(realtime_lines({"P": sweep}, 0.05))
    assert ("the per-episode differences to sync of the 1 delayed setting whose estimate is within the margin "
            "have a standard deviation of 0.25, so a 95% interval reaches about +/-0.049") in text
    assert "shown within the margin only where its estimate is above -0.001" in text
    assert "needs about 199 paired episodes" in text
    far = {"realtime-sync": sweep["realtime-sync"], "realtime-async-d8": sweep["realtime-async-d8"]}
    assert "What the margin asks" not in "\n".join(realtime_lines({"P": far}, 0.05))  # no setting near sync


def test_real_time_figures_stay_readable_with_many_policies_and_strategies(tmp_path, monkeypatch):
    """The real-time figure draws each policy's plain sweep (async, blocking) and leaves strategy sweeps
    ("P + ensemble") to the strategies' figure, which lays seven policies out in a grid (four panels a row at most),
    not in one row."""
    from bcbench.analysis import figures, strategies

    drawn = []
    monkeypatch.setattr(figures, "save_png", lambda fig, path: drawn.append(fig) or path)
    base = np.random.default_rng(0).uniform(0.3, 0.9, 100)
    sweep = {"realtime-sync": _setting(base), "realtime-async-d2": _setting(base - 0.1),
             "realtime-blocking-d2": _setting(base)}
    # a sweep's strategy is read from its records, not its label: "P + MLP" below is a naive sweep
    ensembled = {k: {**v, "summary": {**v["summary"], "strategy": {"strategy": "ensemble"}}} for k, v in sweep.items()}
    by_label = {f"P{i}": sweep for i in range(7)} | {f"P{i} + ensemble": ensembled for i in range(7)}
    figures.realtime_figure(by_label, tmp_path / "realtime.png")
    ax = drawn[0].axes[0]
    assert len(ax.get_legend().get_texts()) == 14  # 7 policies x (async, blocking), no strategy sweep
    assert "7 strategy sweeps in the strategies' figure" in ax.get_title()
    figures.realtime_figure({"P + MLP": sweep, "P + MLP + ensemble": ensembled}, tmp_path / "realtime.png")
    assert [t.get_text() for t in drawn[-1].axes[0].get_legend().get_texts()] == ["P + MLP, async", "P + MLP, blocking"]
    per_policy = {f"P{i}": {"naive": sweep, "ensemble": sweep} for i in range(7)}
    monkeypatch.setattr(strategies.plt, "close", lambda fig: drawn.append(fig))
    strategies.strategy_figure(per_policy, tmp_path / "strategies.png")
    visible = [a for a in drawn[-1].axes if a.get_visible()]
    assert len(visible) == 7 and len({round(a.get_position().y0, 3) for a in visible}) == 2  # two rows
    assert (tmp_path / "strategies.png").stat().st_size > 1000


def test_real_time_figures_count_delay_in_their_tasks_steps_and_draw_its_budgets(tmp_path, monkeypatch):
    """A MetaWorld sweep (80 Hz, 3 actions executed a chunk): delay in 0.0125 s steps, success rate on the score
    axis, and real-time Figure 5's lines at 12.5 and 37.5 ms; Push-T's sweeps keep 0.1 s, mean score, 100 / 800 ms."""
    from bcbench.analysis import figures, strategies

    drawn = []
    monkeypatch.setattr(figures, "save_png", lambda fig, path: drawn.append(fig) or path)
    monkeypatch.setattr(strategies.plt, "close", lambda fig: drawn.append(fig))
    base = np.random.default_rng(0).uniform(0.3, 0.9, 100)

    def sweep(task: dict | None, horizon: int) -> dict:
        out = {"realtime-sync": _setting(base, 20.0), "realtime-async-measured": _setting(base - 0.1, 20.0),
               "realtime-async-d2": _setting(base - 0.1)}
        return {k: {**v, "policy": {"config": {"action_horizon": horizon}}, **({"task": task} if task else {})}
                for k, v in out.items()}

    for task, horizon, step, word, lines in (
            ({"name": "metaworld/pick-place", "control_hz": 80.0}, 3, "0.0125 s", "success rate", [12.5, 37.5]),
            (None, 8, "0.1 s", "mean score", [100.0, 800.0])):
        figures.realtime_figure({"P": sweep(task, horizon)}, tmp_path / "realtime.png")
        assert f"control steps of {step} at" in drawn[-1].axes[0].get_xlabel()
        figures.figure5_realtime({"P": sweep(task, horizon)}, tmp_path / "fig5rt.png")
        dashed = [ln.get_xdata()[0] for ln in drawn[-1].axes[0].lines if ln.get_linestyle() == "--"]
        assert sorted(dashed) == lines
        strategies.strategy_figure({"P": {"naive": sweep(task, horizon)}}, tmp_path / "s.png")
        ax = drawn[-1].axes[0]
        assert f"control steps of {step})" in ax.get_xlabel() and ax.get_ylabel().startswith(word)


def test_a_strategy_is_judged_safe_against_the_plain_sync_score_not_its_own():
    """A strategy that costs 0.2 everywhere, sync included, stays within the margin of its OWN sync at every delay;
    against the policy's plain (naive) sync it keeps nothing, which is how the strategies' table judges it and how
    the real-time section must too (it called such a sweep safe up to d = 8 at 1,600 Hz)."""
    from bcbench.analysis.realtime import safe_delay_sentence
    from bcbench.analysis.report import realtime_lines

    base = np.random.default_rng(3).uniform(0.4, 0.9, 100)

    def sweep(offset: float, kind: str) -> dict:
        out = {"realtime-sync": _setting(base + offset),
               **{f"realtime-blocking-d{d}": _setting(base + offset) for d in (1, 2, 4, 8)},
               "realtime-blocking-measured": _setting(base + offset, median_ms=5.0)}
        for r in out.values():
            r["summary"]["strategy"] = {"strategy": kind}
        return out

    naive, ensemble = sweep(0.0, "naive"), sweep(-0.2, "ensemble")
    assert "blocking d = 8" in safe_delay_sentence(ensemble, 0.05)  # against its own sync: "safe" to d = 8
    lines = "\n".join(realtime_lines({"P": naive, "P + ensemble": ensemble}, 0.05))
    mine = next(line for line in lines.splitlines() if line.startswith("- P + ensemble:"))
    assert f"Against the plain sync score ({base.mean():.3f}, naive's)" in mine
    assert "blocking d = 0: no delay is shown within the margin (d = 1 minus sync: blocking -0.200" in mine
    assert "sync " + f"{base.mean() - 0.2:.3f}" in mine  # its own scores are still listed as measured
    plain = next(line for line in lines.splitlines() if line.startswith("- P:"))
    assert "Against" not in plain and "blocking d = 8" in plain
