"""The evaluation harness end to end on the baselines, with a couple of short episodes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bcbench.errors import BCBenchError
from bcbench.evaluation.evaluate import EvalConfig, evaluate
from bcbench.policies import REGISTRY, is_learned, make_policy
from bcbench.stats import bootstrap_ci, score_summary
from bcbench.tasks.pusht.env import dp_initial_state


def test_harness_on_a_baseline_with_two_episodes(tmp_path):
    cfg = EvalConfig(episodes=2, max_steps=24, workers=2, video=1)
    result = evaluate(make_policy("random"), cfg, tmp_path, progress=False)
    on_disk = json.loads((tmp_path / "eval.json").read_text())
    assert on_disk["summary"]["n"] == 2
    for key in ("policy", "eval_config", "summary", "episodes", "git_commit", "hardware", "versions"):
        assert key in on_disk
    assert on_disk["hardware"]["torch_threads"] >= 1 and on_disk["hardware"]["cpu_model"]
    eps = result["episodes"]
    assert [e["seed"] for e in eps] == [100000, 100001]
    np.testing.assert_allclose(eps[1]["initial_state"], dp_initial_state(100001))
    for e in eps:
        assert 0.0 <= e["score"] <= 1.0 and 1 <= e["length"] <= 24
    assert eps[0]["video"] and (tmp_path / "videos").is_dir() and eps[1]["video"] is None
    s = result["summary"]
    assert s["env_steps"] == sum(e["length"] for e in eps)
    assert s["policy_calls"] == 3  # 24 steps / 8 actions per chunk, both episodes in one batch


def test_evaluation_is_deterministic():
    cfg = EvalConfig(episodes=2, max_steps=16, workers=1)
    a = evaluate(make_policy("scripted"), cfg, None, progress=False)
    b = evaluate(make_policy("scripted"), cfg, None, progress=False)
    assert [e["score"] for e in a["episodes"]] == [e["score"] for e in b["episodes"]]


@pytest.mark.parametrize("name", sorted(n for n in REGISTRY if not is_learned(n)))
def test_baselines_return_chunks(name):
    policy = make_policy(name)
    obs = {"image": np.zeros((3, 2, 96, 96, 3), np.uint8), "agent_pos": np.full((3, 2, 2), 200, np.float32)}
    chunk = policy.predict_action_chunk(obs)
    assert chunk.shape == (3, policy.pred_horizon, 2)
    assert np.isfinite(chunk).all() and chunk.min() >= 0 and chunk.max() <= 512


def test_bad_eval_config_and_unknown_policy():
    with pytest.raises(BCBenchError):
        EvalConfig(episodes=0)
    with pytest.raises(BCBenchError):
        EvalConfig(episodes=2, video=3)
    with pytest.raises(BCBenchError, match="unknown policy"):
        make_policy("nope")
    with pytest.raises(BCBenchError, match="unknown preset"):
        make_policy("random", "huge")


def test_bootstrap_intervals():
    lo, hi = bootstrap_ci(np.array([0.0, 1.0] * 20))
    assert lo < 0.5 < hi and lo > 0.3 and hi < 0.7
    assert bootstrap_ci(np.zeros(40)) == (0.0, 0.0)
    s = score_summary(np.array([0.2, 0.6, 0.95, 1.0]), np.array([0, 0, 0, 1]), np.array([0.1, 0.5, 0.9, 0.96]))
    assert s["share_above_0.5"]["value"] == 0.75 and s["share_above_0.9"]["value"] == 0.5
    assert s["success_rate"]["value"] == 0.25


def _per_seed(result: dict) -> dict[int, tuple]:
    eps = result["episodes"]
    return {e["seed"]: (e["score"], e["max_coverage"], e["length"], tuple(e["final_state"])) for e in eps}


def test_an_episode_depends_only_on_its_own_seed():
    """Per-seed results of seeds 100000-100002 do not change with --episodes or --workers (random policy:
    every action is drawn from the episode's noise stream)."""
    runs = [evaluate(make_policy("random"), EvalConfig(episodes=n, workers=w, max_steps=40), None, progress=False)
            for n, w in ((3, 1), (6, 1), (3, 2), (6, 2))]
    first = _per_seed(runs[0])
    for r in runs[1:]:
        assert {s: v for s, v in _per_seed(r).items() if s in first} == first
    assert len({v[3][2:] for v in first.values()}) == 3  # the episodes really differ
    other = evaluate(make_policy("random", seed=1), EvalConfig(episodes=3, workers=1, max_steps=40), None,
                     progress=False)
    assert _per_seed(other) != first  # and the policy seed matters


@pytest.mark.parametrize("name", ["diffusion", "bet"])
def test_stochastic_policy_chunks_do_not_depend_on_the_batch(name):
    """A learned stochastic policy's chunk for an episode is the same alone or batched with others."""
    import torch

    from bcbench.data.normalizer import MinMaxNormalizer
    from bcbench.evaluation.controller import ChunkedController
    from bcbench.policies.learned import PolicyRunner
    from tests.tiny import tiny_overrides

    torch.manual_seed(0)
    world = np.array([[0.0, 0.0], [512.0, 512.0]])
    norm = MinMaxNormalizer.fit({"agent_pos": world, "action": world})
    runner = PolicyRunner(make_policy(name, "quick", **tiny_overrides(name)), norm)
    rng = np.random.default_rng(0)
    obs = {i: {"pixels": rng.integers(0, 256, (96, 96, 3), dtype=np.uint8),
               "agent_pos": rng.uniform(0, 512, 2).astype(np.float32)} for i in range(4)}

    def first_actions(env_ids: list[int]) -> dict[int, np.ndarray]:
        ctl = ChunkedController(runner)
        for i in env_ids:
            ctl.reset(i, obs[i], seed=100_000 + i)
        return ctl.act(env_ids)

    alone = first_actions([2])
    batched = first_actions([0, 1, 2, 3])
    # same noise; only float rounding of batched matrix products may differ (measured: 3e-5 px)
    np.testing.assert_allclose(alone[2], batched[2], atol=1e-3, rtol=0)
    assert not np.array_equal(batched[0], batched[1]) or name == "bet"


def test_two_level_bootstrap_widens_with_training_seed_variance():
    """Seeds that disagree widen the interval and take the variance share; identical seeds give one-level width."""
    from bcbench.stats import two_level_bootstrap

    rng = np.random.default_rng(0)
    eps = rng.uniform(0, 1, 100)
    alike = [{100_000 + i: float(s) for i, s in enumerate(eps)} for _ in range(3)]
    apart = [{100_000 + i: float(s) + shift for i, s in enumerate(eps)} for shift in (-0.2, 0.0, 0.2)]
    a, b = two_level_bootstrap(alike, n_boot=2000), two_level_bootstrap(apart, n_boot=2000)
    assert a["value"] == pytest.approx(eps.mean()) and b["value"] == pytest.approx(eps.mean())
    assert a["training_seed_share"] == 0.0 and b["training_seed_share"] > 0.9
    assert b["ci95"][1] - b["ci95"][0] > 2 * (a["ci95"][1] - a["ci95"][0])
    assert b["per_seed"] == pytest.approx([eps.mean() - 0.2, eps.mean(), eps.mean() + 0.2])
    paired = two_level_bootstrap(apart, [alike], n_boot=2000)  # apart minus alike, per episode within each seed
    assert paired["value"] == pytest.approx(0.0, abs=1e-12) and paired["ci95"][0] < 0 < paired["ci95"][1]


@pytest.mark.parametrize(("df", "quantile"), [(1, 12.7062047), (2, 4.3026527), (4, 2.7764451), (30, 2.0422725)])
def test_t_quantile_matches_the_tables(df, quantile):
    from bcbench.stats import t_quantile

    assert t_quantile(0.975, df) == pytest.approx(quantile, abs=1e-6)
    assert t_quantile(0.025, df) == pytest.approx(-quantile, abs=1e-6)


def test_over_training_seeds_gives_the_t_interval_of_the_seed_means_and_keeps_the_bootstrap_beside_it():
    """Three seeds 0.2 apart: the interval is mean +/- t(0.975, 2) s / sqrt(3) of the seed means, far wider than the
    two-level bootstrap's; paired against another setting it is the t interval of the per-seed differences; seeds that
    agree get the episodes-only interval of all their episodes (Jackson et al.'s widened Hartung-Knapp)."""
    from bcbench.stats import over_training_seeds, two_level_bootstrap

    eps = np.random.default_rng(0).uniform(0, 1, 100)
    apart = [{100_000 + i: float(s) + shift for i, s in enumerate(eps)} for shift in (-0.2, 0.0, 0.2)]
    est = over_training_seeds(apart, n_boot=2000)
    half = 4.3026527 * 0.2 / np.sqrt(3)  # the seed means' SD is exactly 0.2
    assert est["value"] == pytest.approx(eps.mean())
    assert est["ci95"] == pytest.approx([eps.mean() - half, eps.mean() + half], abs=1e-6)
    assert est["ci95_bootstrap"] == two_level_bootstrap(apart, n_boot=2000)["ci95"]
    assert est["ci95"][0] < est["ci95_bootstrap"][0] and est["ci95"][1] > est["ci95_bootstrap"][1]
    assert est["interval"] == "t over 3 training seeds"
    alike = [{100_000 + i: float(s) for i, s in enumerate(eps)} for _ in range(3)]
    paired = over_training_seeds(apart, [alike, [{k: v - 1 for k, v in a.items()} for a in alike]], n_boot=2000)
    assert paired["per_seed"] == pytest.approx([-0.2, 0.0, 0.2])  # against the better alternative, per seed
    assert paired["ci95"] == pytest.approx([-half, half], abs=1e-6)
    same = over_training_seeds(alike, n_boot=2000)  # seeds that agree exactly: no narrower than their episodes allow
    floor = 1.959964 * np.sqrt(eps.var(ddof=1) / 100 / 3)
    assert same["ci95"] == pytest.approx([eps.mean() - floor, eps.mean() + floor], abs=1e-6)
    one = over_training_seeds(apart[:1], n_boot=2000)  # one seed: no t interval, the episode bootstrap
    assert one["ci95"] == one["ci95_bootstrap"] and one["interval"] == "two-level bootstrap"


def test_seeds_to_decide_projects_the_same_interval_to_more_seeds():
    """The smallest k whose interval, max(t_{k-1} sd, z sqrt(within)) / sqrt(k), excludes every bound."""
    from bcbench.stats import seeds_to_decide

    spread = [0.017 - 0.05, 0.017, 0.017 + 0.05]  # estimate +0.017, per-seed SD 0.05
    assert seeds_to_decide(spread, 1e-8, [-0.05]) == 5  # 2.776 * 0.05 / sqrt(5) = 0.062 < 0.067 < 0.080 (k = 4)
    assert seeds_to_decide(spread, 1e-8, [-0.05, 0.05]) > 5  # the upper bound is only 0.033 away
    assert seeds_to_decide([-0.1, 0.0, 0.1], 1e-8, [0.0]) is None  # an estimate on the bound: never
    assert seeds_to_decide([-0.02, -0.02, -0.02], 0.02**2, [-0.05]) == 2  # agreeing seeds: the episodes' floor only


def test_with_three_seeds_the_t_interval_covers_and_the_two_level_bootstrap_does_not():
    """The reason reports use t (benchmarks/seed_intervals.py at full size): seeds that differ by SD 0.08 around the
    true mean, 100 episodes of SD 0.25 each; 200 simulated studies, seeded."""
    from bcbench.stats import over_training_seeds

    rng = np.random.default_rng(7)
    hits = np.zeros(2)
    for r in range(200):
        x = rng.normal(0.0, 0.08, 3)[:, None] + rng.normal(0.0, 0.25, (3, 100))  # (seeds, episodes)
        est = over_training_seeds([dict(enumerate(row)) for row in x], seed=r, n_boot=400)
        hits += [est["ci95"][0] <= 0 <= est["ci95"][1], est["ci95_bootstrap"][0] <= 0 <= est["ci95_bootstrap"][1]]
    t_cover, boot_cover = hits / 200
    assert t_cover >= 0.91 and boot_cover <= 0.88


def test_a_tree_copied_to_another_machine_is_stamped_with_the_commit_its_launcher_declares(tmp_path, monkeypatch):
    """A lent GPU machine gets the files and, at best, a stale snapshot of .git: $BCBENCH_COMMIT names the commit
    that was copied there and wins; without it, git's HEAD (or None outside a repository)."""
    from bcbench.utils.system import git_commit

    monkeypatch.setenv("BCBENCH_COMMIT", "dc693ca")
    assert git_commit.__wrapped__(tmp_path) == git_commit.__wrapped__() == "dc693ca"
    monkeypatch.delenv("BCBENCH_COMMIT")
    assert git_commit.__wrapped__(tmp_path) is None  # no repository here
    assert len(git_commit.__wrapped__().removesuffix("-dirty")) == 40  # this repository's HEAD


def test_paired_evals_gives_b_minus_a_over_the_shared_seeds(tmp_path, capsys):
    """scripts/paired_evals.py: the difference of two evaluations of one model (e.g. CPU and GPU), paired by seed."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("paired_evals", Path(__file__).parents[1] / "scripts/paired_evals.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"episodes": [{"seed": s, "score": 0.5} for s in range(10)]}))
    b.write_text(json.dumps({"episodes": [{"seed": s, "score": 0.5 + 0.1 * (s < 5)} for s in range(3, 12)]}))
    assert mod.main([str(a), str(b), "--out", str(tmp_path / "p.json")]) == 0
    out = json.loads((tmp_path / "p.json").read_text())
    assert out["episodes"] == 7 and out["same_score_episodes"] == 5  # seeds 3-9; 3 and 4 differ
    assert out["b_minus_a"] == pytest.approx(0.2 / 7) and out["ci95"][0] <= out["b_minus_a"] <= out["ci95"][1]
    assert "over 7 shared episodes" in capsys.readouterr().out
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(SystemExit, match="not an evaluation result"):
        mod.main([str(a), str(tmp_path / "bad.json")])
