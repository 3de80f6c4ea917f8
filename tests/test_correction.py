"""A2C2's correction head (`bcbench train --policy correction`, `--strategy correction`): an untrained head is the
base exactly, the base stays frozen, the controller's per-step hook and its cost in the measured latency."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from bcbench.errors import BCBenchError
from bcbench.evaluation.config import EvalConfig, StrategyConfig
from bcbench.evaluation.latency_sources import LatencySource
from bcbench.evaluation.strategies import Strategy
from bcbench.policies.checkpoint import build_model, load_correction, load_runner
from bcbench.policies.config import config_to_dict
from bcbench.policies.correction import CorrectionConfig, CorrectionRunner
from bcbench.training.loop import TrainOptions, new_run, train
from bcbench.utils.io import read_json
from tests.test_strategies import Planned, _drive, _runner, _same
from tests.tiny import tiny_overrides


def _head_overrides(base: Path, **extra) -> dict:
    return {"base": str(base), "hidden": [8], "max_age": 6, "base_sampler": "ddim", "base_steps": 2,
            "optim.batch_size": 4, "optim.log_every": 1, "optim.checkpoint_every": 2, "optim.warmup_steps": 0,
            "optim.max_steps": 3, "optim.precision": "fp32", **extra}


@pytest.fixture(scope="module")
def base_run(synthetic_zarr, tmp_path_factory) -> Path:
    """A tiny Diffusion Policy trained two steps on the synthetic data: the frozen base."""
    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False, device="cpu")
    run = new_run("diffusion", "quick", {**tiny_overrides("diffusion", max_steps=2), "optim.precision": "fp32"},
                  tmp_path_factory.mktemp("base") / "dp", opts)
    train(run, opts)
    return run


def _untrained_head(base: Path) -> CorrectionRunner:
    cfg = CorrectionConfig.preset("quick")
    cfg.base, cfg.hidden, cfg.max_age = str(base), (8,), 6
    model = build_model({"policy": "correction", "config": config_to_dict(cfg)})
    return CorrectionRunner(model, model.base.normalizer, "untrained")


def test_an_untrained_head_executes_the_base_exactly_episode_by_episode(base_run):
    from bcbench.evaluation.evaluate import evaluate

    base, head = load_runner(base_run), _untrained_head(base_run)
    base.model.set_sampler("ddim", 2)
    for execution, d in (("sync", 0), ("async", 2), ("blocking", 2)):  # step by step, every action equal
        naive = _drive(base, "naive", execution, d, seed=5)
        assert _same(_drive(base, "correction", execution, d, seed=5, head=head, correction="untrained"), naive)
    runs = {}
    for kind in ("naive", "correction"):  # and in the simulator, episode by episode
        cfg = EvalConfig(episodes=2, max_steps=20, workers=1, execution="async", latency_ms=250,
                         strategy=StrategyConfig(kind, correction="untrained" if kind == "correction" else None))
        runs[kind] = evaluate(base, cfg, None, progress=False, head=head if kind == "correction" else None)
    assert [e["final_state"] for e in runs["naive"]["episodes"]] == [e["final_state"]
                                                                     for e in runs["correction"]["episodes"]]
    timing = runs["correction"]["summary"]["strategy"]
    assert timing["head"]["run_dir"] == "untrained" and timing["per_step_ms"]["calls"] > 10  # recorded per step


def test_the_head_trains_on_a_frozen_base_and_then_acts(base_run, synthetic_zarr, tmp_path):
    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False, device="cpu",
                        callbacks=(lambda r: seen.update(run=r),))
    seen: dict = {}
    run = new_run("correction", "quick", _head_overrides(base_run), tmp_path / "head", opts)
    summary = train(run, opts)
    model = seen["run"].model
    assert summary["step"] == 3  # and the head alone trained: the base is none of its parameters
    assert summary["parameters"] == sum(p.numel() for p in model.mlp.parameters()) < model.base.model.num_parameters()
    frozen = load_runner(base_run).model.state_dict()
    assert all(torch.equal(v, frozen[k]) for k, v in model.base.model.state_dict().items())  # untouched
    assert {k.split(".")[0] for k in model.state_dict()} == {"mlp", "base_digest"}  # nothing of the base saved
    head = load_correction(run)
    base = load_runner(base_run)
    assert head.model.trained_on() == base.info.weights_sha256
    from bcbench.utils.io import sha256_file

    ckpt = max((run / "checkpoints").glob("step_*"), key=lambda p: int(p.name.split("_")[-1]))
    assert head.describe()["weights_sha256"] == sha256_file(next(ckpt.glob("*.safetensors")))  # records name it
    assert head.model.mlp[-1].weight.abs().sum() > 0  # trained: the residual is no longer zero
    base.model.set_sampler("ddim", 2)
    naive = _drive(base, "naive", "async", 2, seed=5)
    for execution in ("async", "blocking"):  # d = 0 is sync, for a head that acts
        sync = _drive(base, "correction", "sync", seed=5, head=head, correction=str(run))
        assert _same(_drive(base, "correction", execution, 0, seed=5, head=head, correction=str(run)), sync)
    assert not _same(_drive(base, "correction", "async", 2, seed=5, head=head, correction=str(run)), naive)
    assert read_json(run / "run.json")["config"]["base"] == str(base_run)


def test_the_heads_windows_put_the_step_index_1_plus_a_plans_for_at_frame_1_plus_a(base_run, synthetic_zarr):
    from bcbench.data.sequence import make_datasets

    head = _untrained_head(base_run).model
    train_ds, _, _ = make_datasets(head.task.demonstrations(str(synthetic_zarr)), 0.1, 0, state_dim=head.state_dim,
                                   **head.data_window())
    idx, ends = train_ds.indices, train_ds.buffer.episode_ends  # (W, 1 + A + ...) steps
    last = ends[np.searchsorted(ends, idx[:, 1], side="right")] - 1  # each window's episode's last step
    for a in range(head.config.max_age + 1):  # frame 1 + a is t0 + a, or the last step once the episode has ended
        assert np.array_equal(idx[:, 1 + a], np.minimum(idx[:, 1] + a, last))
    assert np.all(idx[:, 1] - idx[:, 0] <= 1)  # at most the base's one repeated first frame


def test_the_heads_cached_chunks_and_features_are_the_bases_own_computed_once(base_run, synthetic_zarr):
    from bcbench.data.sequence import frames, make_datasets

    head = _untrained_head(base_run).model
    head.base.model.set_sampler("ddim", 2)
    train_ds, _, _ = make_datasets(head.task.demonstrations(str(synthetic_zarr)), 0.1, 0, state_dim=head.state_dim,
                                   **head.data_window())
    head.attach_data(train_ds)
    batch = {k: torch.from_numpy(v) for k, v in train_ds.get_batch(np.arange(6)).items()}
    assert "image" not in batch  # the head reads frames by step, once each
    window, pos, k = batch["steps"][:, :2], batch["agent_pos"][:, :2], torch.tensor([0, 1, 0, 1, 0, 1])
    image = torch.from_numpy(frames(train_ds.buffer, window.numpy()))  # (6, 2, 3, H, W)
    feats = head.cached_features(window)
    assert torch.allclose(torch.cat([feats, pos], -1).flatten(1), head.features(image, pos), atol=1e-5)
    plans = head.cached_plans(window[:, 1], k)  # the base's own chunk from the batch's observation, with its seed
    episodes = np.searchsorted(train_ds.buffer.episode_ends, window[:, 1].numpy(), side="right")
    for i in range(6):  # one noise per (episode, draw)
        seed = np.random.SeedSequence([0, int(episodes[i]), int(k[i])]).generate_state(1, np.uint64)[0] >> 2
        own = head.base.model.predict_action_chunk({"image": image[i:i + 1], "agent_pos": pos[i:i + 1],
                                                    "generators": [torch.Generator().manual_seed(int(seed))]})
        assert torch.allclose(plans[i], own[0], atol=1e-4)
    assert not torch.allclose(plans, head.cached_plans(window[:, 1], 1 - k))  # the other draw: another chunk
    done = head._plans_ok.clone()
    head.base.model.predict_action_chunk = None  # a further call would fail: both are served from the caches
    assert torch.equal(head.cached_plans(window[:, 1], k), plans) and torch.equal(head._plans_ok, done)
    assert torch.equal(head.cached_features(window), feats)


def test_a_resumed_head_trains_to_the_same_weights(base_run, synthetic_zarr, tmp_path, monkeypatch):
    monkeypatch.setattr("bcbench.policies.correction.CACHE_BLOCK", 8)  # several blocks, filled in another order
    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False, device="cpu")
    straight = new_run("correction", "quick", _head_overrides(base_run, **{"optim.max_steps": 4}), tmp_path / "a", opts)
    train(straight, opts)
    cut = new_run("correction", "quick", _head_overrides(base_run, **{"optim.max_steps": 4}), tmp_path / "b", opts)

    class Cut(Exception):
        pass

    def stop(r):
        if r.state.step == 3:
            raise Cut

    with pytest.raises(Cut):
        train(cut, TrainOptions(data=str(synthetic_zarr), threads=1, progress=False, device="cpu", callbacks=(stop,)))
    assert read_json(cut / "checkpoints" / "latest.json")["step"] == 2
    train(cut, opts)  # resumed from its step-2 checkpoint: the caches are rebuilt, to the same values
    a, b = load_correction(straight).model.state_dict(), load_correction(cut).model.state_dict()
    assert all(torch.equal(a[n], b[n]) for n in a)


def _record(base_run: Path, path: Path | None, episodes: int = 2, max_steps: int = 12) -> dict:
    from bcbench.evaluation.evaluate import evaluate

    base = load_runner(base_run)
    base.model.set_sampler("ddim", 2)
    cfg = EvalConfig(episodes=episodes, max_steps=max_steps, workers=1, execution="async", latency_ms=250)
    return evaluate(base, cfg, None, progress=False, record=path)


def test_a_recorded_rollout_replays_to_its_own_frames(base_run, tmp_path):
    from bcbench.data.rollouts import load_rollouts, rollout_attrs
    from bcbench.tasks import get_task

    result = _record(base_run, tmp_path / "r.npz")
    plain = _record(base_run, None)  # recording changes nothing of the episodes
    assert [e["final_state"] for e in result["episodes"]] == [e["final_state"] for e in plain["episodes"]]
    buf, attrs = load_rollouts(tmp_path / "r.npz"), rollout_attrs(tmp_path / "r.npz")
    assert list(np.diff(np.concatenate([[0], buf.episode_ends]))) == [e["length"] for e in result["episodes"]]
    assert attrs["task"] == "pusht" and attrs["policy"]["weights_sha256"] == load_runner(base_run).info.weights_sha256
    task = get_task("pusht")
    for i, e in enumerate(result["episodes"]):  # the recorded actions, replayed from the seed, give the frames back
        steps = range(buf.episode_starts[i], buf.episode_ends[i])
        env = task.make_episode(e["seed"], None)
        obs, _, _ = env.reset()
        for t in steps:
            assert np.array_equal(obs["pixels"], buf.images[t]) and np.allclose(obs["agent_pos"], buf.state[t])
            obs = env.step(buf.action[t])[0]
        env.close()


def _nearest_by_hand(head, stale, start, shift):
    """The draw among the K chunks at `start` closest to the stale chunk on the steps both plan, sample by sample."""
    out = []
    for b in range(len(start)):
        s, n = int(shift[b]), head.config.pred_horizon - 1 - int(shift[b])  # steps both plan: stale 1 + s.., later 1..
        gaps = [float(((head.cached_plans(start[b:b + 1], torch.tensor([j]))[0, 1:1 + n] - stale[b, 1 + s:1 + s + n])
                       ** 2).mean()) for j in range(head.config.plan_draws)]
        out.append(int(np.argmin(gaps)))
    return torch.tensor(out)


@pytest.mark.parametrize(("target", "frames", "draw"), [("fresh", None, "same"), ("sync", None, "same"),
                                                        ("sync", 1, "same"), ("sync", None, "nearest")])
def test_a_head_on_its_bases_rollouts_learns_the_bases_own_action(base_run, tmp_path, target, frames, draw):
    from bcbench.data.sequence import make_datasets

    _record(base_run, tmp_path / "r.npz", episodes=3, max_steps=30)
    opts = TrainOptions(threads=1, progress=False, device="cpu", callbacks=(lambda r: seen.update(run=r),))
    seen: dict = {}
    overrides = _head_overrides(base_run, rollouts=str(tmp_path / "r.npz"), target=target, max_age=14,
                                head_frames=frames, target_draw=draw, **{"optim.batch_size": 2})
    run = new_run("correction", "quick", overrides, tmp_path / "head", opts)
    train(run, opts)
    head = seen["run"].model
    assert read_json(run / "normalizer.json") == load_runner(base_run).normalizer.to_dict()  # the base's units
    train_ds, _, _ = make_datasets(head.training_data(None), 0.1, 0, state_dim=head.state_dim, **head.data_window())
    batch = {k: torch.from_numpy(v) for k, v in train_ds.get_batch(np.arange(2)).items()}
    last = len(train_ds) - 1  # the last window of the last episode: every age past a few runs off its end
    batch = {k: torch.from_numpy(v) for k, v in train_ds.get_batch(np.array([0, 1, last, last])).items()}
    torch.manual_seed(3)
    loss = head.compute_loss(batch)
    torch.manual_seed(3)  # the same draws of k and the age, by hand
    k = (torch.rand(4) * head.config.plan_draws).long()
    age = (torch.rand(4) * (head.config.max_age + 1)).long()
    steps, index, rows = batch["steps"], 1 + age, torch.arange(4)
    planned = head.cached_plans(steps[:, 1], k)[rows, index]
    cols = torch.stack([index - 1, index], 1)[:, 2 - (frames or 2):]  # (4, frames): the newest, ending at t0 + a
    feats = torch.cat([head.cached_features(steps[rows[:, None], cols]), batch["agent_pos"][rows[:, None], cols]], -1)
    # fresh: what the base plans at t0 + a; sync: what sync execution runs there, from the chunk j steps before
    j = age % head.config.action_horizon if target == "sync" else torch.zeros_like(age)
    drawn = k
    if draw == "nearest":  # the later chunk's draw in the stale chunk's mode; within one action horizon its own
        drawn = _nearest_by_hand(head, head.cached_plans(steps[:, 1], k), steps[rows, index - j], age - j)
        assert torch.equal(drawn[age < 8], k[age < 8])
        assert not torch.equal(drawn, k)  # these draws (seed 3) pick another draw for an older chunk
    own = head.cached_plans(steps[rows, index - j], drawn)[rows, 1 + j]
    if target == "sync":
        assert torch.equal(own[age < 8], planned[age < 8])  # an age within one action horizon is its own target
        assert bool((age >= 8).any() & (age < 8).any()), age  # both kinds drawn
    err = ((planned + head.residual(feats.flatten(1), planned, age, index) - own) ** 2).mean(-1)
    real = steps[rows, index] == steps[:, 1] + age  # not past the episode's end
    assert 0 < int(real.sum()) < 4, age  # the draws put one of the last windows' ages past the end
    assert torch.allclose(loss, err[real].mean())
    _script("head_open_loop").main([str(run), str(tmp_path / "open.json"), "--windows", "3", "--threads", "1"])
    rows = read_json(tmp_path / "open.json")["by_age"]
    assert len(rows) == 15 and all(r["runner_minus_training_px"] < 1e-2 for r in rows)  # runner = training path
    if target == "sync":
        assert rows[0]["mse_stale"] == 0.0  # age 0: the stale chunk is its own target


def test_a_head_refuses_rollouts_of_other_weights(base_run, tmp_path):
    from bcbench.data.rollouts import Recorder

    rec = Recorder()
    obs = {"pixels": np.zeros((96, 96, 3), np.uint8), "agent_pos": np.zeros(2, np.float32)}
    rec.reset(0, 5, obs)
    rec.acted(0, np.zeros(2))
    rec.write(tmp_path / "other.npz", {"task": "pusht", "policy": {"weights_sha256": "ab" * 32}})
    cfg = CorrectionConfig.preset("quick")
    cfg.base, cfg.target, cfg.rollouts = str(base_run), "fresh", str(tmp_path / "other.npz")
    head = build_model({"policy": "correction", "config": config_to_dict(cfg)})
    with pytest.raises(BCBenchError, match="other weights"):
        head.training_data(None)


def _store(path: Path, seeds: list[int], lengths: list[int], weights: str) -> Path:
    from bcbench.data.rollouts import Recorder

    rec = Recorder()
    for ep, (seed, n) in enumerate(zip(seeds, lengths, strict=True)):
        rec.reset(ep, seed, {"pixels": np.full((96, 96, 3), seed % 250, np.uint8), "agent_pos": np.zeros(2)})
        for t in range(n):
            rec.acted(ep, np.array([seed, t], np.float32))
            rec.observed(ep, {"pixels": np.zeros((96, 96, 3), np.uint8), "agent_pos": np.full(2, t + 1.0)})
    return rec.write(path, {"task": "pusht", "policy": {"weights_sha256": weights}})


def test_joined_rollouts_keep_every_episode_in_order_and_refuse_another_base(tmp_path):
    from bcbench.data.rollouts import load_rollouts

    join = _script("join_rollouts").join
    a, b = _store(tmp_path / "a.npz", [0, 1], [3, 2], "ab" * 32), _store(tmp_path / "b.npz", [7], [4], "ab" * 32)
    join(str(tmp_path / "u.npz"), [str(a), str(b)])
    u = load_rollouts(tmp_path / "u.npz")
    assert list(u.episode_ends) == [3, 5, 9] and u.action[5].tolist() == [7, 0] and u.action[4].tolist() == [1, 1]
    assert list(np.load(tmp_path / "u.npz")["seeds"]) == [0, 1, 7]
    other = _store(tmp_path / "c.npz", [9], [2], "cd" * 32)
    with pytest.raises(BCBenchError, match="differ in weights"):
        join(str(tmp_path / "v.npz"), [str(a), str(other)])
    assert not (tmp_path / "v.npz").exists()


@pytest.mark.parametrize(("overrides", "message"), [
    ({"rollouts": "x.npz"}, "target=fresh"),
    ({"target": "expert"}, "target must be demo, fresh or sync"),
    ({"target_draw": "mean"}, "target_draw must be same or nearest"),
    ({"target_draw": "nearest"}, "it needs target=fresh or sync"),
])
def test_head_settings_that_cannot_train_say_why(base_run, tmp_path, overrides, message):
    opts = TrainOptions(threads=1, progress=False, device="cpu")
    with pytest.raises(BCBenchError, match=message):
        new_run("correction", "quick", _head_overrides(base_run, **overrides), tmp_path / "h", opts)


def _script(name: str, folder: str = "scripts"):
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, Path(__file__).parents[1] / folder / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_memorization_script_measures_both_splits(base_run, synthetic_zarr, tmp_path):
    _script("head_memorization").main([str(base_run), str(tmp_path / "m.json"), "--steps", "2", "--windows", "4",
                                       "--threads", "1", "--data", str(synthetic_zarr)])
    out = read_json(tmp_path / "m.json")
    assert out["base_weights_sha256"] == load_runner(base_run).info.weights_sha256
    for split in ("training", "held_out"):
        assert len(out[split]["mse_by_age"]) == 15 and out[split]["mse"] > 0


def test_the_strategy_cost_benchmark_times_the_heads_per_step_hook_alone(base_run, tmp_path):
    """benchmarks/strategy_cost.py with a head: the hook's own calls at batch 1 (rounds x calls, interleaved with
    the requests) beside the requests, the head it ran named; without a head the correction strategy is refused."""
    bench = _script("strategy_cost", "benchmarks")
    bench.main([str(base_run), "--sampler", "ddim", "--steps", "2", "--strategies", "naive", "correction",
                "--correction", "untrained", "--rounds", "3", "--calls", "2", "--warmup", "1", "--threads", "1",
                "--out", str(tmp_path)])
    out = read_json(tmp_path / "strategy-cost.json")
    hook = out["strategies"]["correction"]["per_step_hook"]
    assert hook["calls"] == 6 and 0 < hook["median_ms"] <= hook["p99_ms"]
    assert hook["head"]["base_weights_sha256"] == load_runner(base_run).info.weights_sha256
    assert "per_step_hook" not in out["strategies"]["naive"] and out["strategies"]["naive"]["calls"] == 6
    with pytest.raises(BCBenchError, match="--correction"):
        bench.main([str(base_run), "--strategies", "naive", "correction", "--out", str(tmp_path)])


class Recording:
    """A correction head that records what the controller gives it and corrects nothing."""

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def correct(self, obs, actions, ages, indices):
        self.calls.append((actions.copy(), ages.copy(), indices.copy()))
        return actions

    def base_mismatch(self, policy):
        return None

    def describe(self):
        return {"name": "recording"}


@pytest.mark.parametrize(("execution", "d"), [("sync", 0), ("async", 3), ("blocking", 2)])
def test_the_head_gets_every_planned_action_with_its_chunks_age_and_index(execution, d):
    head = Recording()
    acts = _drive(Planned(), "correction", execution, d, steps=40, head=head, correction="x")
    # steps where the agent holds its last target (waiting for a chunk) are not corrected: async holds for the first
    # chunk's delay only (later ones arrive just in time), blocking for every chunk's
    assert len(head.calls) == {"sync": 40, "async": 40 - d, "blocking": 40 - 4 * d}[execution]
    planned_steps = []
    for actions, ages, indices in head.calls:
        assert actions.shape == (1, 2) and ages.shape == indices.shape == (1,)
        planned_steps.append(actions[0, 0])  # Planned: entry j of a call at step t plans step t + j
        if execution == "blocking":  # observed at the request, executed from its arrival d steps later
            assert ages[0] == indices[0] + d and 0 <= indices[0] < 8
        else:  # chunk_start 0: the index is the age; async skips the d actions in the past
            assert ages[0] == indices[0] and d <= ages[0] < 8
    if execution != "blocking":  # every step from the first chunk's arrival on, each with the action planned for it
        assert planned_steps == list(range(40 - len(head.calls), 40))
    assert all(acts[t][0] == t for t in range(40 - len(head.calls), 40)) or execution == "blocking"


def test_the_heads_per_step_cost_is_in_the_measured_latency():
    class Clocked:
        name, obs_horizon, pred_horizon, action_horizon, chunk_start = "clocked", 2, 16, 8, 1

        def __init__(self, s: float) -> None:
            self.s, self.last_compute_s = s, 0.0

        def predict_action_chunk(self, obs):
            self.last_compute_s = self.s
            return np.zeros((len(obs["agent_pos"]), 16, 2), np.float32)

        def describe(self):
            return {"name": self.name}

    class Timed(Recording):
        last_compute_s = 0.005  # reports 5 ms a step (a SelfTimedPolicy)

    def measured(seconds: float) -> float:
        src, policy = LatencySource("measured"), Clocked(seconds)
        src.resolve(policy, Strategy(StrategyConfig("correction", correction="x"), policy, head=Timed()))
        return float(np.median(src.samples_ms))

    assert measured(0.03) == pytest.approx(35.0, abs=0.5)  # one step: the chunk and one head call
    assert measured(0.25) == pytest.approx(265.0, abs=0.5)  # three steps, a head call in each


def test_heads_that_cannot_run_say_why_in_one_line(base_run, synthetic_zarr, tmp_path, capsys):
    from bcbench.cli.main import main

    head = _untrained_head(base_run)
    with pytest.raises(BCBenchError, match=r"was trained on the base .* not on this policy"):
        Strategy(StrategyConfig("correction", correction="x"), _runner("diffusion"), head=head)
    with pytest.raises(BCBenchError, match="needs its trained head"):
        Strategy(StrategyConfig("correction", correction="x"), _runner("diffusion"))
    with pytest.raises(BCBenchError, match="--strategy correction needs its head"):
        StrategyConfig("correction")
    with pytest.raises(BCBenchError, match="goes with --strategy correction"):
        Strategy(StrategyConfig(), _runner("diffusion"), head=head)
    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False, device="cpu", eval_every=1)
    with pytest.raises(BCBenchError, match="--eval-every rolls out a policy"):
        train(new_run("correction", "quick", _head_overrides(base_run), tmp_path / "h", opts), opts)
    with pytest.raises(BCBenchError, match="is a correction head, not a policy"):
        load_runner(tmp_path / "h")
    with pytest.raises(BCBenchError, match="needs its base run"):
        build_model({"policy": "correction", "config": config_to_dict(CorrectionConfig())})
    common = ["realtime", "--checkpoint", str(base_run), "--episodes", "1", "--delays", "1", "--execution", "async",
              "--max-steps", "5", "--quiet", "--out", str(tmp_path / "rt")]
    for extra, message in ((["--strategy", "correction"], "--strategy correction needs its head"),
                           (["--strategy", "naive", "--correction", str(tmp_path / "h")], "goes with --strategy")):
        assert main([*common, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0]
