"""Training-time delay conditioning (training-time RTC, Black et al. 2025) and `--strategy prefix`: the plain network
unchanged, the prefix given clean and left out of the loss, the strategy's d = 0 and refusal rules."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from bcbench.errors import BCBenchError
from bcbench.evaluation.config import StrategyConfig
from bcbench.evaluation.controller import episode_generator
from bcbench.evaluation.latency_sources import LatencySource
from bcbench.evaluation.strategies import Strategy, prefix_mask, prefix_weights
from bcbench.interface import example_observation
from bcbench.policies import make_policy
from bcbench.policies.prefix import Prefix, delay_mask
from bcbench.policies.unet1d import ConditionalUnet1D
from bcbench.training.parts import step_noise
from tests.test_strategies import _drive, _runner, _same
from tests.tiny import tiny_overrides

POLICIES = ["flow", "diffusion"]


def _model(name: str, **overrides):
    torch.manual_seed(0)
    return make_policy(name, "quick", **tiny_overrides(name), **overrides)


def _batch(model, rows: int = 4, step: int = 0) -> dict:
    g = torch.Generator().manual_seed(11)
    obs = {"image": torch.rand(rows, 2, 3, 96, 96, generator=g),
           "agent_pos": torch.rand(rows, 2, 2, generator=g) * 2 - 1,
           "action": torch.rand(rows, 16, 2, generator=g) * 2 - 1}
    return step_noise(obs, model.config.seed, step, slice(0, rows), rows)


@pytest.mark.parametrize("name", POLICIES)
def test_without_the_feature_the_network_and_loss_are_todays(name):
    """delay_train = (0, 0): Diffusion Policy's U-Net (2 channels in and out, the same parameters) and the loss of
    the formula as it was, from the same draws, bit for bit; the sampler's loop is left as it is."""
    plain = _model(name)
    c = plain.config
    assert not plain.delay_conditioned and c.delay_train == (0, 0)
    torch.manual_seed(0)
    ref = ConditionalUnet1D(2, c.obs_horizon * (plain.encoder.out_dim + 2), c.step_embed_dim, c.down_dims,
                            c.kernel_size, c.n_groups)
    assert {k: v.shape for k, v in plain.unet.state_dict().items()} == {k: v.shape for k, v in ref.state_dict().items()}
    plain.eval()  # the centre crop: the random one draws from the global stream
    batch = _batch(plain)
    loss = plain.compute_loss(batch)
    again = _batch(plain)  # the same step's generator: the same draws
    cond = plain.encode(again["image"], again["agent_pos"])
    action = again["action"]
    noise = plain.train_draw(again, torch.randn, (16, 2))
    if name == "diffusion":
        t = (plain.train_draw(again, torch.rand) * 100).long().clamp_(max=99)
        noisy = plain.sqrt_ac[t, None, None] * action + plain.sqrt_1m_ac[t, None, None] * noise
        expected = F.mse_loss(plain.unet(noisy, t, cond), noise)
    else:
        t = 1.0 - plain.train_draw(again, torch.rand) ** (1 / 1.5)
        x_t = (1 - t)[:, None, None] * noise + t[:, None, None] * action
        expected = F.mse_loss(plain.velocity(x_t, t, cond), action - noise)
    assert torch.equal(loss, expected)
    f = lambda x, t: x  # noqa: E731
    assert plain.prefixed(f, None) is f  # no wrapper around the plain denoiser


@pytest.mark.parametrize("name", POLICIES)
def test_the_prefix_is_given_clean_and_left_out_of_the_loss(name):
    """The U-Net reads the clean actions and a 1 on the prefix, and the loss has no gradient there."""
    model = _model(name, delay_train=(2, 5))
    assert model.unet.down_modules[0][0].blocks[0][0].in_channels == 3  # actions + the mask
    seen = {}

    def hook(module, args, out):
        seen["input"] = args[0]
        out.retain_grad()
        seen["output"] = out

    model.unet.register_forward_hook(hook)
    batch = _batch(model, rows=6)
    model.compute_loss(batch).backward()
    x, out = seen["input"], seen["output"]
    mask = x[..., 2]  # (B, Tp)
    d = mask.sum(1)
    assert ((d >= 2) & (d <= 5)).all() and len(set(d.tolist())) > 1  # d per row, in the range
    np.testing.assert_array_equal(mask.numpy(), delay_mask(d.long(), 1, 16).numpy())  # from the current step on
    on = mask > 0
    assert torch.equal(x[..., :2][on], batch["action"][on])  # clean, not noised
    assert (out.grad[on] == 0).all() and (out.grad[~on] != 0).any()  # out of the loss, and only there


def test_delay_ranges_are_validated_in_one_line():
    for bad, match in (((3, 2), "0 <= lo <= hi"), ((0, 15), "pred_horizon - obs_horizon = 14"),
                       ((0,), "two whole numbers")):
        with pytest.raises(BCBenchError, match=match):
            make_policy("flow", "quick", **tiny_overrides("flow"), delay_train=bad)


@pytest.mark.parametrize("name", POLICIES)
def test_an_empty_prefix_samples_as_the_plain_sampler_and_a_prefix_is_kept(name):
    """A conditioned model with no clean action samples as its own plain sampler would (the first chunk of an
    episode, or d = 0), bit for bit; with a prefix the chunk returns it exactly and the rest changes."""
    runner = _runner(name, delay_train=(0, 6))
    obs = example_observation(3, 2, seed=2)

    def gens():
        return [episode_generator(0, i) for i in range(3)]
    plain = runner.predict_action_chunk({**obs, "generators": gens()})
    target = np.full((3, 16, 2), 200.0, np.float32)
    empty = runner.predict_prefixed_chunk({**obs, "generators": gens()}, target, np.zeros((3, 16), np.float32))
    assert np.array_equal(plain, empty)
    mask = delay_mask(torch.tensor([1, 3, 6]), 1, 16).numpy()
    given = runner.predict_prefixed_chunk({**obs, "generators": gens()}, target, mask)
    on = mask > 0
    assert np.array_equal(given[on], target[on]) and not np.allclose(given[~on], plain[~on])


def test_the_prefix_strategy_gives_the_actions_the_delay_executes():
    """From the controller's soft mask: the frozen actions from the current step on, never the past index."""
    w = prefix_weights(16, 1 + 3, 12)  # chunk_start 1, d = 3
    np.testing.assert_array_equal(prefix_mask(w[None], 1)[0], [0, 1, 1, 1] + [0] * 12)
    assert prefix_mask(prefix_weights(16, 1, 12)[None], 1).sum() == 0  # d = 0 (sync): no prefix

    class Prefixed:  # records the prefix it is given; plans (t + j, call)
        name, obs_horizon, pred_horizon, action_horizon, chunk_start = "prefixed", 2, 16, 8, 1

        def __init__(self):
            self.calls = []

        def prefix_unavailable(self):
            return None

        def predict_action_chunk(self, obs):
            t = obs["agent_pos"][:, -1, 0] / 7.0
            k = np.arange(16) - 1
            return np.stack([t[:, None] + k, np.full((len(t), 16), float(len(self.calls)))], -1).astype(np.float32)

        def predict_prefixed_chunk(self, obs, prefix, mask):
            self.calls.append((round(float(obs["agent_pos"][0, -1, 0]) / 7.0), prefix[0].copy(), mask[0].copy()))
            return np.where(mask[..., None] > 0, prefix, self.predict_action_chunk(obs))

        def describe(self):
            return {"name": self.name}

    d = 3
    rec = Prefixed()
    acts = _drive(rec, "prefix", "async", d, steps=50)
    assert len(rec.calls) > 4
    assert rec.calls[0][2][1:1 + d].tolist() == [1.0] * d  # the first chunk: the held position is what executes
    for t, prefix, mask in rec.calls[1:]:
        if t + d > len(acts):
            continue
        assert mask.tolist() == [0.0] + [1.0] * d + [0.0] * (15 - d)
        for j in range(d):  # what runs while the chunk computes, exactly what it was given
            np.testing.assert_array_equal(acts[t + j], prefix[1 + j])
            assert acts[t + j][0] == t + j  # the previous chunk's plan for that step


@pytest.mark.parametrize("execution", ["async", "blocking"])
def test_prefix_at_zero_delay_is_sync_and_naive_and_acts_under_delay(execution):
    runner = _runner("flow", delay_train=(0, 6))
    for seed in (100000, 100001):
        sync = _drive(runner, "prefix", "sync", seed=seed)
        assert _same(_drive(runner, "prefix", execution, 0, seed=seed), sync)
        assert _same(sync, _drive(runner, "naive", "sync", seed=seed))  # no prefix in sync: the plain sampler
    assert not _same(_drive(runner, "prefix", "async", 3, seed=7), _drive(runner, "naive", "async", 3, seed=7))


def test_a_model_trained_without_the_feature_refuses_prefix_in_one_line():
    for name in ("flow", "diffusion"):
        with pytest.raises(BCBenchError, match=r"trained without delay conditioning \(delay_train = \(0, 0\)\)"):
            Strategy(StrategyConfig("prefix"), _runner(name))
    with pytest.raises(BCBenchError, match="bct was trained without delay conditioning"):
        Strategy(StrategyConfig("prefix"), _runner("bct"))
    with pytest.raises(BCBenchError, match="cannot continue a clean prefix"):
        Strategy(StrategyConfig("prefix"), make_policy("scripted"))
    with pytest.raises(BCBenchError, match="cannot take a clean prefix"):  # the network itself, too
        _model("flow").predict_action_chunk(_model("flow").example_obs(1), prefix=Prefix(torch.zeros(1, 16, 2),
                                                                                          torch.zeros(1, 16)))


def test_the_prefix_request_is_timed_in_the_measured_latency():
    class Clocked:
        name, obs_horizon, pred_horizon, action_horizon, chunk_start = "clocked", 2, 16, 8, 1
        last_compute_s = 0.0

        def prefix_unavailable(self):
            return None

        def predict_action_chunk(self, obs):
            self.last_compute_s = 0.03
            return np.zeros((len(obs["agent_pos"]), 16, 2), np.float32)

        def predict_prefixed_chunk(self, obs, prefix, mask):
            out = self.predict_action_chunk(obs)
            self.last_compute_s = 0.04 if mask.sum() > 0 else 0.0  # only a prefixed request costs this
            return out

        def describe(self):
            return {"name": self.name}

    src = LatencySource("measured")
    policy = Clocked()
    src.resolve(policy, Strategy(StrategyConfig("prefix"), policy))
    assert float(np.median(src.samples_ms)) == pytest.approx(40.0, abs=1.0)


def test_a_delay_conditioned_run_records_its_range_and_sweeps_with_prefix(synthetic_zarr, tmp_path, capsys):
    from bcbench.cli.main import main
    from bcbench.policies.checkpoint import load_runner
    from bcbench.training.loop import TrainOptions, new_run, train
    from bcbench.utils.io import read_json

    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False, device="cpu")
    runs = {}
    for label, extra in (("plain", {}), ("delay", {"delay_train": [0, 4]})):
        runs[label] = new_run("flow", "quick", {**tiny_overrides("flow", max_steps=2), **extra}, tmp_path / label,
                              opts)
        train(runs[label], opts)
    assert read_json(runs["delay"] / "run.json")["config"]["delay_train"] == [0, 4]
    assert load_runner(runs["delay"]).prefix_unavailable() is None
    common = ["realtime", "--episodes", "1", "--delays", "1", "--execution", "async", "--max-steps", "8", "--quiet"]
    assert main([*common, "--checkpoint", str(runs["delay"]), "--strategy", "naive", "prefix",
                 "--out", str(tmp_path / "rt")]) == 0
    record = read_json(tmp_path / "rt" / "prefix" / "realtime-sweep.json")
    assert record["study"]["variant"]["strategy"] == "prefix"
    capsys.readouterr()
    rc = main([*common, "--checkpoint", str(runs["plain"]), "--strategy", "prefix", "--out", str(tmp_path / "no")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "trained without delay conditioning" in err
    assert not (tmp_path / "no").exists()
    # a delay longer than the trained range would give the network a clean prefix it never saw: refused first
    long = ["realtime", "--episodes", "1", "--delays", "1", "6", "--execution", "async", "--max-steps", "8", "--quiet"]
    rc = main([*long, "--checkpoint", str(runs["delay"]), "--strategy", "prefix", "--out", str(tmp_path / "long")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "trained with delays 0-4" in err and "--delays 6" in err
    assert not (tmp_path / "long").exists()
