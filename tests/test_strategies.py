"""Execution strategies (naive, rtc, bid, ensemble): the acceptance checks of issue 31, on fakes whose chunks say
what they were planned for and on tiny flow and Diffusion Policy networks."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from bcbench.data.normalizer import MinMaxNormalizer
from bcbench.errors import BCBenchError
from bcbench.evaluation.config import STRATEGIES, EvalConfig, StrategyConfig
from bcbench.evaluation.controller import ChunkedController, episode_generator
from bcbench.evaluation.latency_sources import LatencySource, steps_for
from bcbench.evaluation.strategies import Strategy, bid_select, prefix_weights
from bcbench.interface import example_observation
from bcbench.policies import make_policy
from bcbench.policies.learned import PolicyRunner
from bcbench.utils.io import read_json
from tests.tiny import tiny_overrides


def _runner(name: str, **overrides) -> PolicyRunner:
    torch.manual_seed(0)
    world = np.array([[0.0, 0.0], [512.0, 512.0]], np.float32)
    model = make_policy(name, "quick", **tiny_overrides(name), **overrides)
    return PolicyRunner(model, MinMaxNormalizer.fit({"agent_pos": world, "action": world}))


class ShiftHead:
    """A correction head that moves every planned action by (age, index): deterministic, and it acts."""

    def correct(self, obs, actions, ages, indices):
        return actions + np.stack([ages, indices], axis=-1).astype(np.float32)

    def base_mismatch(self, policy):
        return None

    def describe(self):
        return {"name": "shift"}


def _obs(t: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(t)
    return {"pixels": rng.integers(0, 256, (96, 96, 3), dtype=np.uint8), "agent_pos": np.array([t * 7.0, 300.0 - t])}


def _drive(policy, strategy: str = "naive", execution: str = "sync", d: int = 0, steps: int = 30, seed: int = 0,
           s: int | None = None, head=None, **params) -> list[np.ndarray]:
    """The actions of one episode of `steps` steps (observations a fixed function of the step)."""
    cfg = StrategyConfig(strategy, **params)
    ctl = ChunkedController(policy, execution=execution, delay=lambda env_id: d, execution_horizon=s,
                            strategy=Strategy(cfg, policy, head=head))
    ctl.reset(0, _obs(0), seed=seed)
    out = []
    for t in range(steps):
        out.append(np.array(ctl.act([0])[0]))
        ctl.observe(0, _obs(t + 1))
    return out


def _same(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_prefix_weights_are_the_papers_soft_mask():
    """RTC eq. 5 (exponential schedule): the example of the official code, start 2, end 6, horizon 10."""
    f = lambda c: c * math.expm1(c) / (math.e - 1)  # noqa: E731
    expected = [1, 1, f(4 / 5), f(3 / 5), f(2 / 5), f(1 / 5), 0, 0, 0, 0]
    np.testing.assert_allclose(prefix_weights(10, 2, 6), expected, rtol=1e-6)
    assert prefix_weights(10, 0, 0).sum() == 0  # no overlap: no guidance
    np.testing.assert_array_equal(prefix_weights(8, 8, 8), np.ones(8))  # everything frozen


@pytest.mark.parametrize("strategy", STRATEGIES)
@pytest.mark.parametrize("execution", ["async", "blocking"])
def test_at_zero_delay_every_strategy_equals_sync_per_seed(strategy, execution):
    # prefix: a model trained with delay conditioning (bcbench.policies.prefix); correction: a head that acts
    runner = _runner("flow", delay_train=(0, 6)) if strategy == "prefix" else _runner("flow")
    params = {"bid_samples": 3} if strategy == "bid" else {"correction": "shift"} if strategy == "correction" else {}
    head = ShiftHead() if strategy == "correction" else None
    for seed in (100000, 100001):
        sync = _drive(runner, strategy, "sync", seed=seed, head=head, **params)
        assert _same(_drive(runner, strategy, execution, 0, seed=seed, head=head, **params), sync)
    if strategy == "naive":  # and the naive strategy is bcbench's execution as it was
        ctl = ChunkedController(runner)
        ctl.reset(0, _obs(0), seed=100000)
        plain = []
        for t in range(30):
            plain.append(np.array(ctl.act([0])[0]))
            ctl.observe(0, _obs(t + 1))
        assert _same(plain, _drive(runner, seed=100000))


@pytest.mark.parametrize("name", ["flow", "diffusion"])
def test_rtc_with_guidance_weight_zero_is_naive_async(name):
    runner = _runner(name)
    for d in (1, 3):
        naive = _drive(runner, "naive", "async", d, seed=7)
        assert _same(_drive(runner, "rtc", "async", d, seed=7, rtc_max_guidance=0.0), naive)
        assert not _same(_drive(runner, "rtc", "async", d, seed=7), naive)  # beta 5: guidance acts


@pytest.mark.parametrize("name", ["flow", "diffusion"])
def test_guided_sampling_moves_the_chunk_towards_the_target(name):
    runner = _runner(name)
    obs = example_observation(4, 2, seed=1)
    plain = runner.predict_action_chunk({**obs, "generators": [episode_generator(0, i) for i in range(4)]})
    target = np.full((4, 16, 2), 256.0, np.float32) + np.linspace(-50, 50, 16)[None, :, None]
    weights = np.broadcast_to(prefix_weights(16, 4, 12), (4, 16))
    guided = runner.predict_guided_chunk({**obs, "generators": [episode_generator(0, i) for i in range(4)]},
                                         target, weights, 5.0)

    def err(chunk):
        return float((np.linalg.norm(chunk - target, axis=-1) * weights).sum())
    assert err(guided) < 0.5 * err(plain)


class Recorder:
    """A guided 'policy' whose chunk entry j of a call at step t is (t + j, call index); it records what the
    controller asks it to follow."""

    name = "recorder"
    obs_horizon, pred_horizon, action_horizon, chunk_start = 2, 16, 8, 1

    def __init__(self) -> None:
        self.calls: list[tuple[int, np.ndarray, np.ndarray]] = []

    def guidance_unavailable(self):
        return None

    def predict_action_chunk(self, obs):
        t = obs["agent_pos"][:, -1, 0] / 7.0  # the newest observation's step (see _obs)
        k = np.arange(16) - self.chunk_start  # index chunk_start is the current step
        chunk = np.stack([t[:, None] + k, np.full((len(t), 16), float(len(self.calls)))], axis=-1)
        return chunk.astype(np.float32)

    def predict_guided_chunk(self, obs, target, weights, max_guidance):
        chunk = self.predict_action_chunk(obs)
        self.calls.append((round(float(obs["agent_pos"][0, -1, 0]) / 7.0), target[0].copy(), weights[0].copy()))
        return chunk

    def describe(self):
        return {"name": self.name}


@pytest.mark.parametrize(("d", "s"), [(1, None), (3, None), (3, 8), (5, 8), (6, None)])
def test_the_frozen_prefix_is_executed_exactly_as_the_previous_chunks_actions(d, s):
    rec = Recorder()
    acts = _drive(rec, "rtc", "async", d, steps=60, s=s)
    assert len(rec.calls) > 4
    for t, target, weights in rec.calls[1:]:
        if t + d > len(acts):
            continue  # it would arrive after the episode
        frozen = np.flatnonzero(weights == 1.0)
        assert list(frozen) == list(range(rec.chunk_start + d))  # the past action and the d of the delay
        for j in range(d):  # what runs while the new chunk computes is the target's frozen part, exactly
            np.testing.assert_array_equal(acts[t + j], target[rec.chunk_start + j])
            if (s or 8 - d) >= d:  # the previous chunk's action planned for that step (s < d: its last one, held)
                assert acts[t + j][0] == t + j
        assert 0 < weights[rec.chunk_start + d] < 1  # then the soft part of the overlap


def test_bid_with_one_sample_is_naive_and_candidates_share_one_encoding():
    runner = _runner("flow")
    for d in (0, 2):
        assert _same(_drive(runner, "bid", "async", d, seed=3, bid_samples=1), _drive(runner, "naive", "async", d,
                                                                                      seed=3))
    obs = {**example_observation(2, 2, seed=4)}

    class Rows:  # the same runner without its batched sampler: the controller repeats the rows
        name, obs_horizon, pred_horizon, action_horizon, chunk_start = "rows", 2, 16, 8, 1
        predict_action_chunk = staticmethod(runner.predict_action_chunk)

    strat = Strategy(StrategyConfig("bid", bid_samples=4), runner)
    a = strat._candidates(runner, {**obs, "generators": [episode_generator(0, i) for i in range(2)]}, 4)
    b = strat._candidates(Rows(), {**obs, "generators": [episode_generator(0, i) for i in range(2)]}, 4)
    assert a.shape == (2, 4, 16, 2)
    np.testing.assert_allclose(a, b, atol=1e-3)  # pixels: float rounding of other batch shapes
    assert not np.allclose(a[:, 0], a[:, 1])  # different noise per candidate


def test_bid_on_a_deterministic_policy_executes_naives_actions():
    """BCT samples nothing: its N candidates are one chunk N times, so BID chooses that chunk and acts as naive (up to
    the float rounding of a larger batch), which is why the study sweeps BCT with naive and ensemble only."""
    runner = _runner("bct")
    bid = _drive(runner, "bid", "async", 2, seed=3, bid_samples=4)
    naive = _drive(runner, "naive", "async", 2, seed=3)
    np.testing.assert_allclose(np.stack(bid), np.stack(naive), atol=1e-3)  # pixels


def test_bid_selects_coherent_candidates_and_contrasts_against_the_weak_policy():
    rng = np.random.default_rng(0)
    cands = rng.normal(0, 10, (6, 16, 2)).astype(np.float32)
    weights = prefix_weights(16, 2, 10)
    assert np.array_equal(bid_select(cands, cands[4], weights, modes=6), cands[4])  # backward: the coherent one
    # forward contrast, no previous chunk: two modes of three candidates each; alone, the first mode's centre wins
    # (ties go to the first); when the weak policy's samples sit on the first mode, a candidate of the second wins
    base = np.zeros((16, 2), np.float32)
    cands = np.stack([base, base + 1, base + 2, base + 40, base + 41, base + 42])
    weak = np.stack([base, base + 1, base + 1, base, base + 2, base])
    none = np.zeros(16, np.float32)
    assert np.array_equal(bid_select(cands, base, none, modes=1), cands[1])
    assert bid_select(cands, base, none, modes=1, weak=weak)[0, 0] >= 40


class Planned:
    """Chunk entry j of a call at step t is (t + j, call index)."""

    name = "planned"
    obs_horizon, pred_horizon, action_horizon, chunk_start = 2, 16, 8, 0

    def __init__(self) -> None:
        self.n = 0

    def predict_action_chunk(self, obs):
        t = obs["agent_pos"][:, -1, 0] / 7.0
        out = np.stack([t[:, None] + np.arange(16), np.full((len(t), 16), float(self.n))], axis=-1)
        self.n += 1
        return out.astype(np.float32)

    def describe(self):
        return {"name": self.name}


def test_ensembling_averages_every_chunks_action_for_the_step():
    m = 0.5
    acts = _drive(Planned(), "ensemble", "sync", steps=24, ensemble_decay=m)
    w = np.exp(-m * np.arange(2))
    for t in range(24):
        assert acts[t][0] == pytest.approx(t)  # every chunk means the same step
        # step t is predicted by call t // 8 and, from the second chunk on, by the call before (its entries 8-15)
        calls = [t // 8 - 1, t // 8] if t >= 8 else [0]
        expected = float(np.dot(w[:len(calls)], calls) / w[:len(calls)].sum())
        assert acts[t][1] == pytest.approx(expected)


class Clocked:
    """Reports a compute time proportional to the rows it sampled (a SelfTimedPolicy), 30 ms per chunk."""

    name = "clocked"
    obs_horizon, pred_horizon, action_horizon, chunk_start = 2, 16, 8, 1
    last_compute_s = 0.0

    def predict_action_chunk(self, obs):
        self.last_compute_s = 0.03 * len(obs["agent_pos"])
        return np.zeros((len(obs["agent_pos"]), 16, 2), np.float32)

    def guidance_unavailable(self):
        return None

    def predict_guided_chunk(self, obs, target, weights, max_guidance):
        out = self.predict_action_chunk(obs)
        self.last_compute_s *= 3  # a forward and a backward pass per step
        return out

    def describe(self):
        return {"name": self.name}


def test_a_strategys_extra_compute_is_in_the_measured_latency():
    def measured(strategy: StrategyConfig) -> float:
        src = LatencySource("measured")
        policy = Clocked()
        src.resolve(policy, Strategy(strategy, policy))
        return float(np.median(src.samples_ms))

    naive = measured(StrategyConfig())
    assert naive == pytest.approx(30.0, abs=1.0) and steps_for(naive / 1e3) == 1
    bid = measured(StrategyConfig("bid", bid_samples=4))  # four chunks per call, and the selection
    assert bid >= 120.0 and steps_for(bid / 1e3) == 2
    assert measured(StrategyConfig("rtc")) == pytest.approx(90.0, abs=1.0)


def test_strategies_are_timed_in_interleaved_rounds_and_a_sweep_takes_those_times(tmp_path, capsys):
    """A sweep of several strategies times them all together before any episode (one after another's episodes ran
    slower, results/strategies-dp-a); the sweep's measured setting uses the times it is given."""
    from bcbench.cli.main import main
    from bcbench.evaluation.latency_sources import interleaved_request_ms
    from bcbench.evaluation.realtime import sweep

    policy = Clocked()
    both = {"naive": Strategy(StrategyConfig(), policy), "rtc": Strategy(StrategyConfig("rtc"), policy)}
    rounds, _ = interleaved_request_ms(policy, both, rounds=3, calls=2, warmup=1)
    assert [len(rounds[k]) for k in ("naive", "rtc")] == [3, 3] and all(len(r) == 2 for r in rounds["rtc"])
    assert np.median(rounds["naive"]) == pytest.approx(30.0, abs=1.0)
    assert np.median(rounds["rtc"]) == pytest.approx(90.0, abs=1.0)
    ticks: list[int] = []  # other work timed in the same rounds (a per-step hook) runs once after each round
    interleaved_request_ms(policy, both, rounds=3, calls=1, warmup=0, each_round=lambda: ticks.append(1))
    assert len(ticks) == 3
    runner = _runner("cnn_mlp")
    given = LatencySource("measured", samples_ms=[250.0] * 100)
    out = sweep(runner, [], ["async"], 1, [], True, progress=False, max_steps=10, measured_source=given)
    source = out["realtime-async-measured"]["summary"]["latency_source"]
    assert source["median_ms"] == 250.0 and source["calls"] == 100  # given, not timed: d = 3
    assert main(["realtime", "--policy", "scripted", "--episodes", "1", "--delays", "1", "--execution", "async",
                 "--strategy", "ensemble", "naive", "--measured", "--max-steps", "10", "--quiet", "--out",
                 str(tmp_path / "rt")]) == 0
    printed = capsys.readouterr().out
    assert "timed in 20 interleaved rounds before any episode: naive" in printed  # naive runs first, whatever order
    assert printed.count("Against the plain sync score") == 1  # ensembling judged against naive's sync; naive not


def test_backend_auto_keeps_a_sweep_with_rtc_in_torch_and_says_why():
    """--measured defaults to --backend auto, whose fastest mode may be an exported graph that cannot take RTC's
    vector-Jacobian product: a sweep with rtc chooses among the torch modes only, and the record says why."""
    from bcbench.cli.parser import build_parser
    from bcbench.cli.policies import _needs_torch
    from bcbench.evaluation.backends import apply_mode

    parse = build_parser().parse_args
    why = _needs_torch(parse(["realtime", "--checkpoint", "r", "--measured", "--strategy", "naive", "rtc"]))
    assert "rtc" in why and "autograd" in why
    assert _needs_torch(parse(["realtime", "--checkpoint", "r", "--measured", "--strategy", "naive", "bid"])) == ""
    assert _needs_torch(parse(["eval", "--checkpoint", "r", "--strategy", "rtc"]))
    runner = _runner("flow")
    apply_mode(runner, "auto", torch_only=why)
    trial = runner.info.deployment["auto"]
    assert runner.info.mode == trial["chosen"] == "fast" and set(trial["median_ms"]) == {"fast"}
    assert why in trial["why"]
    Strategy(StrategyConfig("rtc"), runner)  # and RTC runs in the mode chosen


def test_diffusion_rtc_inpaints_the_clean_estimate_at_flows_fraction_and_never_overshoots():
    """Diffusion Policy's carry-over (policies.guidance): x0 moves towards the target by min(1, (1 - tau) w(tau)),
    tau the flow time of the state; all the way while tau <= 1/2, less near the data, nothing with beta = 0."""
    from bcbench.policies.guidance import Guide, inpaint_clean

    x0, target = torch.zeros(1, 16, 2), torch.ones(1, 16, 2)
    weights = torch.from_numpy(prefix_weights(16, 4, 12))[None]  # (1, Tp)
    moved = inpaint_clean(x0, 0.0025, Guide(target, weights, 5.0))  # abar = 0.0025: tau = 0.05
    assert torch.allclose(moved[0, :, 0], weights[0])  # fraction 1: the mask itself
    for abar in np.linspace(1e-6, 1 - 1e-6, 50):
        frac = float(inpaint_clean(x0, float(abar), Guide(target, torch.ones(1, 16), 5.0))[0, 0, 0])
        a, s = math.sqrt(abar), math.sqrt(1 - abar)
        tau = a / (a + s)
        assert 0.0 < frac <= 1.0 and frac == pytest.approx(min(1.0, 5 * (1 - tau), (tau ** 2 + (1 - tau) ** 2) / tau),
                                                           rel=1e-5)
    assert torch.equal(inpaint_clean(x0, 0.5, Guide(target, weights, 0.0)), x0)


def test_diffusion_rtc_needs_no_backward_pass_and_runs_in_an_exported_graph(monkeypatch):
    """No Jacobian: DP's guided sampler runs where flow's cannot (an exported OpenVINO graph), equal to its torch
    form, and `auto` is not held to torch for it (flow's is)."""
    from bcbench.evaluation import backends
    from bcbench.evaluation.backends import apply_mode

    runner = _runner("diffusion")
    assert not runner.model.guidance_autograd and runner.guidance_unavailable() is None
    obs = example_observation(2, 2, seed=3)
    target = np.full((2, 16, 2), 300.0, np.float32)
    weights = np.broadcast_to(prefix_weights(16, 4, 12), (2, 16))

    def guided():
        gens = [episode_generator(0, i) for i in range(2)]
        return runner.predict_guided_chunk({**obs, "generators": gens}, target, weights, 5.0)
    ref = guided()
    apply_mode(runner, "openvino-fp32")
    assert runner.guidance_unavailable() is None
    np.testing.assert_allclose(guided(), ref, atol=1e-2)  # pixels: the graph's float rounding only
    asked = {}

    def choose(runner, apply, candidates=None, restriction=""):  # what auto would time, without timing it
        asked[runner.name] = candidates
        return {"chosen": "fast", "why": restriction}
    monkeypatch.setattr(backends, "choose_mode", choose)
    for name in ("diffusion", "flow"):
        apply_mode(_runner(name), "auto", torch_only="rtc's guidance needs autograd: torch only")
    assert asked == {"diffusion": None, "flow": ("fast",)}  # None: every exact mode a candidate


def test_flow_rtc_without_the_jacobian_moves_the_clean_estimate_by_the_fraction():
    """--rtc-no-jacobian (J = I): the guided velocity lands the clean estimate x + (1 - tau) v' exactly
    clean_fraction(tau) of the way to the target on the mask; beta = 0 is the unguided velocity."""
    from bcbench.policies.guidance import Guide, clean_fraction, guided_velocity

    x = torch.randn(2, 16, 2, generator=torch.Generator().manual_seed(0))
    target = torch.ones(2, 16, 2)
    weights = torch.from_numpy(prefix_weights(16, 4, 12))[None].repeat(2, 1)  # (B, Tp)

    def velocity(x_in):
        return 0.5 * x_in - 0.2  # any field
    for tau in (0.0, 0.3, 0.5, 0.8, 0.95):
        v = guided_velocity(velocity, x, tau, Guide(target, weights, 5.0, jacobian=False))
        a1 = x + (1 - tau) * velocity(x)
        expected = a1 + clean_fraction(tau, 5.0) * weights[..., None] * (target - a1)
        assert torch.allclose(x + (1 - tau) * v, expected, atol=1e-6)
        assert 0.0 < clean_fraction(tau, 5.0) <= 1.0
    assert torch.equal(guided_velocity(velocity, x, 0.3, Guide(target, weights, 0.0, jacobian=False)), velocity(x))


def test_flow_rtc_without_the_jacobian_runs_in_an_exported_graph_and_leaves_auto_free():
    from bcbench.cli.parser import build_parser
    from bcbench.cli.policies import _needs_torch
    from bcbench.evaluation.backends import apply_mode

    runner = _runner("flow")
    for d in (1, 3):  # guidance 0 is naive in this form too; beta 5 acts
        naive = _drive(runner, "naive", "async", d, seed=7)
        assert _same(_drive(runner, "rtc", "async", d, seed=7, rtc_max_guidance=0.0, rtc_jacobian=False), naive)
        assert not _same(_drive(runner, "rtc", "async", d, seed=7, rtc_jacobian=False), naive)
    obs = example_observation(2, 2, seed=3)
    target = np.full((2, 16, 2), 300.0, np.float32)
    weights = np.broadcast_to(prefix_weights(16, 4, 12), (2, 16))

    def guided(jacobian):
        gens = [episode_generator(0, i) for i in range(2)]
        return runner.predict_guided_chunk({**obs, "generators": gens}, target, weights, 5.0, jacobian)
    ref, with_jacobian = guided(False), guided(True)
    assert not np.allclose(ref, with_jacobian)  # another method, not the paper's under a new name
    apply_mode(runner, "openvino-fp32")
    assert runner.guidance_unavailable(jacobian=False) is None and runner.guidance_unavailable() is not None
    np.testing.assert_allclose(guided(False), ref, atol=1e-2)  # pixels: the graph's float rounding only
    Strategy(StrategyConfig("rtc", rtc_jacobian=False), runner)  # accepted in the exported mode
    parse = build_parser().parse_args
    assert _needs_torch(parse(["realtime", "--checkpoint", "r", "--measured", "--strategy", "rtc",
                               "--rtc-no-jacobian"])) == ""
    assert Strategy(StrategyConfig("rtc", rtc_jacobian=False), _runner("flow")).describe()["jacobian"] is False
    assert StrategyConfig("rtc", rtc_jacobian=False).variant_extra() == {"rtc_jacobian": False}  # sweep records
    assert StrategyConfig("rtc").variant_extra() == {} and "jacobian" not in Strategy(StrategyConfig("rtc"),
                                                                                       _runner("flow")).describe()


def test_strategies_that_cannot_run_say_why_in_one_line():
    with pytest.raises(BCBenchError, match="bct does not sample its chunk"):
        Strategy(StrategyConfig("rtc"), _runner("bct"))
    runner = _runner("flow")
    runner.model.deployed, runner.model.deployment = {}, {"backend": "openvino"}  # as an exported graph would be
    with pytest.raises(BCBenchError, match=r"vector-Jacobian product .* exported openvino graph"):
        Strategy(StrategyConfig("rtc"), runner)
    with pytest.raises(BCBenchError, match="--strategy must be one of"):
        StrategyConfig("smooth")
    with pytest.raises(BCBenchError, match="--bid-weak goes with --strategy bid"):
        StrategyConfig("rtc", bid_weak="runs/x")
    assert EvalConfig(strategy={"strategy": "bid", "bid_samples": 4}).strategy.bid_samples == 4  # from a record


def test_the_report_names_rtcs_form_when_it_is_not_the_papers(tmp_path):
    """A sweep of RTC with J = I shows as 'rtc (J = I)', still paired with the same policy's naive sweep."""
    from bcbench.analysis.strategies import load_strategy_sweeps, strategy_table
    from bcbench.utils.io import write_json

    def record(kind: str, extra: dict) -> dict:
        episodes = [{"seed": 100_000 + i, "score": 0.5 + 0.1 * (kind == "rtc") * (i % 2)} for i in range(4)]
        summary = {"mean_score": {"value": 0.5, "ci95": [0.4, 0.6]}, "n": 4}
        settings = {name: {"episodes": episodes, "summary": summary, "realtime": {"setting": name}}
                    for name in ("realtime-sync", "realtime-async-d4")}
        return {"type": "realtime", "study": {"name": "t", "label": "flow" + ("" if kind == "naive" else
                f" + {kind}"), "variant": {"strategy": kind, **extra}}, "margin": 0.05, "settings": settings}
    write_json(tmp_path / "naive" / "realtime-sweep.json", record("naive", {}))
    write_json(tmp_path / "rtc" / "realtime-sweep.json", record("rtc", {"rtc_jacobian": False}))
    sweeps = load_strategy_sweeps(tmp_path)
    assert list(sweeps) == ["flow"] and sorted(sweeps["flow"]) == ["naive", "rtc (J = I)"]
    assert any("| flow | rtc (J = I) |" in line for line in strategy_table(sweeps, 0.05))


def test_realtime_sweeps_each_strategy_and_the_report_pairs_them_with_naive(tmp_path, capsys):
    from bcbench.analysis.strategies import load_strategy_sweeps, strategy_lines
    from bcbench.cli.main import main

    out = tmp_path / "rt"
    assert main(["realtime", "--policy", "scripted", "--episodes", "2", "--delays", "2", "--execution", "async",
                 "--strategy", "naive", "ensemble", "--ensemble-decay", "0.5", "--out", str(out), "--max-steps", "30",
                 "--quiet"]) == 0
    for kind in ("naive", "ensemble"):
        assert sorted(p.name for p in (out / kind).glob("realtime-*.json")) == [
            "realtime-async-d2.json", "realtime-sweep.json", "realtime-sync.json"]
    rec = read_json(out / "ensemble" / "realtime-async-d2.json")
    assert rec["eval_config"]["strategy"]["strategy"] == "ensemble" and rec["summary"]["strategy"]["decay"] == 0.5
    assert (out / "strategies.png").stat().st_size > 1000
    printed = capsys.readouterr().out
    assert "| scripted | ensemble |" in printed  # the table, paired with naive
    sweeps = load_strategy_sweeps(out)
    assert list(sweeps) == ["scripted"] and sorted(sweeps["scripted"]) == ["ensemble", "naive"]
    text = "\n".join(strategy_lines(sweeps, 0.05))  # the report's section (a study's report: tests/test_study.py)
    assert "## Execution strategies under latency" in text and "| scripted | ensemble |" in text
    # a strategy that cannot run on the policy fails before any episode, in one line
    assert main(["realtime", "--policy", "scripted", "--episodes", "2", "--delays", "2", "--strategy", "naive", "rtc",
                 "--out", str(tmp_path / "no"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--strategy rtc: scripted has no guided sampler" in err[0]
    assert not (tmp_path / "no").exists()


@pytest.mark.parametrize(("args", "message"), [
    (["--strategy", "bid", "--bid-weak", "runs/x"], "--bid-weak goes with a trained --checkpoint"),
    (["--strategy", "rtc", "--bid-weak", "runs/x"], "--bid-weak goes with --strategy bid"),
    (["--strategy", "smooth"], "invalid choice: 'smooth'"),
    (["--strategy", "bid", "--bid-samples", "0"], "expected a number >= 1"),
    (["--strategy", "rtc"], "--strategy rtc: scripted has no guided sampler"),
])
def test_bad_strategy_input_is_one_line_exit_2(args, message, capsys):
    from bcbench.cli.main import main

    try:
        rc = main(["eval", "--policy", "scripted", "--episodes", "1", "--max-steps", "5", "--quiet", *args])
    except SystemExit as e:  # argparse's own check of the value
        rc = e.code
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_rtc_outside_its_own_execution_horizon_rule_is_noted(capsys):
    """RTC is defined for s >= d; the default horizon s = 8 - d breaks that for d > 4: allowed, but said."""
    from bcbench.evaluation.realtime import sweep

    runner = _runner("flow")
    runner.model.set_sampler("euler", 1)
    for s, noted in [(None, True), (6, False)]:
        sweep(runner, [6], ["async"], episodes=1, profiles=[], measured=False, progress=False, max_steps=2,
              execution_horizon=s, strategy=StrategyConfig("rtc"))
        err = capsys.readouterr().err
        assert ("note: rtc at d = 6 executes fewer actions per chunk than the delay" in err) == noted, s


def test_a_horizon_no_chunk_allows_fails_before_any_episode(capsys):
    """d = 8 with s = 8 needs 17 actions of Diffusion Policy's 16 (the current step's at index 1): the sweep says
    so before its first setting, not after the settings before d = 8 ran (a lost sweep, results/strategies-confirm)."""
    from bcbench.cli.main import main
    from bcbench.evaluation.realtime import sweep

    runner = _runner("diffusion")
    calls = []
    runner.predict_action_chunk = lambda obs: calls.append(1)  # any episode would call it
    with pytest.raises(BCBenchError, match=r"async d = 8 with execution horizon 8 needs 17 actions .* at s = 8 the "
                                           r"delays can be \[1, 2, 4, 6\], at d = 8 s can be at most 7"):
        sweep(runner, [1, 2, 4, 6, 8], ["async"], 1, [], False, progress=False, execution_horizon=8)
    assert not calls
    assert main(["realtime", "--policy", "scripted", "--episodes", "1", "--delays", "1", "16", "--execution", "async",
                 "--quiet"]) == 2
    assert "async d = 16 with execution horizon 1" in capsys.readouterr().err


def test_a_sweep_keeps_each_finished_setting_and_resumes_from_them(tmp_path, monkeypatch):
    from bcbench.cli.main import main
    from bcbench.evaluation import realtime

    real, calls, fail_at = realtime.evaluate, [], [3]

    def failing_third(*args, **kwargs):
        calls.append(1)
        if len(calls) == fail_at[0]:
            raise BCBenchError("the machine went away")
        return real(*args, **kwargs)

    monkeypatch.setattr(realtime, "evaluate", failing_third)
    out = tmp_path / "rt"
    assert main(["realtime", "--policy", "scripted", "--episodes", "1", "--delays", "1", "2", "--execution", "async",
                 "--max-steps", "10", "--quiet", "--out", str(out)]) == 2
    assert sorted(p.name for p in out.glob("*.json")) == ["realtime-async-d1.json", "realtime-sync.json"]
    # --resume keeps what matches exactly and runs only the rest; another episode count keeps nothing
    calls.clear()
    fail_at[0] = 0  # no failure this time
    args = ["realtime", "--policy", "scripted", "--episodes", "1", "--delays", "1", "2", "--execution", "async",
            "--max-steps", "10", "--quiet", "--out", str(out), "--resume"]
    assert main(args) == 0 and len(calls) == 1  # d = 2 only
    assert main(args) == 0 and len(calls) == 1  # everything kept
    assert main([*args[:4], "2", *args[5:]]) == 0 and len(calls) == 4  # 2 episodes: sync, d = 1, d = 2 again


def test_strategy_cells_regenerate_the_committed_readme_table():
    """scripts/strategy_cells.py rebuilds results/strategies-confirm/README.md's cells from the committed records
    (section 6: naive at d = 4 against sync; RTC at d = 4 against sync and against naive); a bad folder is one line
    on stderr and exit 2."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    run = [sys.executable, str(repo / "scripts" / "strategy_cells.py")]
    out = subprocess.run([*run, str(repo / "results/strategies-confirm/flow-euler2-default")], capture_output=True,
                         text=True, check=True).stdout
    readme = (repo / "results/strategies-confirm/README.md").read_text()
    for cell in ("0.661, -0.216 [-0.286, -0.150]", "0.723, -0.154 [-0.211, -0.094] / +0.062 [-0.011, +0.139]"):
        assert cell in out and cell in readme
    bad = subprocess.run([*run, str(repo / "no-such-folder")], capture_output=True, text=True)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1


def test_recovery_regenerates_the_committed_d8_shares_on_one_machine():
    """scripts/recovery.py rebuilds results/strategies-confirm-long/README.md's one-machine d = 8 table from the
    committed records: the study's own sync and default-horizon naive d = 8 (settings of its sweep records, named
    after a colon) against RTC and naive at s = 7; a sweep without a setting named is one line and exit 2."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    study = repo / "results/cpu-confirm-dpflow-long/runs/diffusion-cpu-s0-21c61ecc/realtime-ddim10.json"
    s7 = repo / "results/strategies-confirm-long/dp-ddim10-s7-torch"
    run = [sys.executable, str(repo / "scripts" / "recovery.py"), "--sync", f"{study}:realtime-sync"]
    out = subprocess.run([*run, "--naive", f"{study}:realtime-async-d8", str(s7 / "rtc/realtime-async-d8.json"),
                          str(s7 / "naive/realtime-async-d8.json")], capture_output=True, text=True, check=True).stdout
    readme = (repo / "results/strategies-confirm-long/README.md").read_text()
    assert "naive sync 0.851, naive at the delay 0.449: loss 0.402" in out
    assert "rtc/realtime-async-d8.json: 0.730, +0.281 [+0.209, +0.352] over naive, recovers 70% [56, 84]" in out
    assert "naive/realtime-async-d8.json: 0.632, +0.183 [+0.106, +0.260] over naive, recovers 45% [29, 60]" in out
    assert "| 0.730, **recovers 70% [56, 84]** of naive's loss | 0.632, 45% [29, 60] |" in readme
    bad = subprocess.run([*run, "--naive", str(study), str(study)], capture_output=True, text=True)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    assert "name one of its settings" in bad.stderr


def test_replicates_regenerate_the_committed_horizon_choice_and_goal_lines():
    """scripts/replicates.py rebuilds results/strategies-replicates/README.md's validation choice of RTC's horizon and
    flow's d = 4 goal line over three noise replicates, and scripts/recovery.py DP's d = 8 share over them, from the
    committed records;
    finds the sync records of one policy equal, and refuses a missing record or records
    of different episodes in one group (one line on stderr, exit 2)."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    val = repo / "results/strategies-replicates/val"
    run = [sys.executable, str(repo / "scripts" / "replicates.py")]
    out = subprocess.run([*run, "diff", str(val / "flow-euler10-s8/rtc/realtime-async-d4.json"),
                          str(val / "flow-euler10-s4/rtc/realtime-async-d4.json")],
                         capture_output=True, text=True, check=True).stdout
    assert "0.801 - 0.782 = +0.019 [-0.046, +0.088]" in out
    assert "+0.019 [-0.046, +0.088]" in (repo / "results/strategies-replicates/README.md").read_text()
    readme = (repo / "results/strategies-replicates/README.md").read_text()
    flow, dp = repo / "results/strategies-replicates/flow-euler10", repo / "results/strategies-replicates/dp-ddim10"
    out = subprocess.run([*run, "diff", f"{flow}/seed*/rtc-d4/rtc/realtime-async-d4.json",
                          f"{flow}/seed*/naive-d8/realtime-sync.json"],
                         capture_output=True, text=True, check=True).stdout
    assert "3 and 3 replicates: 0.820 - 0.869 = -0.049 [-0.088, -0.014]" in out and "-0.049 [-0.088, -0.014]" in readme
    recovery = [sys.executable, str(repo / "scripts" / "recovery.py")]  # the d = 8 line takes replicate groups too
    out = subprocess.run([*recovery, "--sync", f"{dp}/seed*/naive-d8/realtime-sync.json", "--naive",
                          f"{dp}/seed*/naive-d8/realtime-async-d8.json",
                          f"{dp}/seed*/rtc-d8/rtc/realtime-async-d8.json"],
                         capture_output=True, text=True, check=True).stdout
    assert "recovers 63% [52, 73]" in out and "**63% [52, 73]**" in readme
    same = subprocess.run([*run, "same", str(val / "dp-ddim10-s*/rtc/realtime-sync.json")],
                          capture_output=True, text=True, check=True).stdout
    assert "2 records, 100 episodes each" in same and float(same.split()[-1]) < 1e-12
    for bad in (["diff", str(val / "nothing.json"), str(val / "nothing.json")],
                ["same", f"{val}/flow-euler10-s4/rtc/realtime-sync.json,"
                         f"{repo}/results/strategies-confirm-long/dp-ddim10-s8/naive/realtime-sync.json"]):
        r = subprocess.run([*run, *bad], capture_output=True, text=True)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
