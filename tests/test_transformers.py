"""BeT and BCT: k-means bins, causal masking where it belongs, BCT's size, k-means in checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bcbench.data import load_replay_buffer
from bcbench.policies import make_policy
from bcbench.policies.bet import kmeans
from bcbench.policies.checkpoint import load_runner
from bcbench.reference import STUDY_PARAMETERS
from bcbench.training.loop import TrainOptions, new_run, prepare, train
from tests.tiny import tiny_overrides


def _obs(b: int = 2, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {"image": torch.rand(b, 2, 3, 96, 96, generator=g), "agent_pos": torch.rand(b, 2, 2, generator=g) * 2 - 1}


def test_kmeans_bins_reproduce_actions():
    rng = np.random.default_rng(0)
    true = rng.uniform(-1, 1, size=(8, 2))
    x = (true[rng.integers(0, 8, 4000)] + rng.normal(0, 0.01, size=(4000, 2))).astype(np.float32)
    centres = kmeans(x, 8, seed=0)
    err = np.sqrt(((x[:, None] - centres[None]) ** 2).sum(-1)).min(1)
    assert err.mean() < 0.03  # every cluster found
    model = make_policy("bet", "quick", **tiny_overrides("bet"))
    model.centres.copy_(torch.from_numpy(centres))
    a = torch.from_numpy(x[:100])
    bins, offsets = model.encode_actions(a)
    torch.testing.assert_close(model.centres[bins] + offsets, a)  # bin + offset is lossless
    assert offsets.abs().max() < 0.1  # and the offsets are small corrections


def test_kmeans_on_real_training_actions(real_zarr):
    buf = load_replay_buffer(real_zarr, images=False)
    from bcbench.data.sequence import fit_normalizer, split_episodes

    train, _ = split_episodes(buf.n_episodes, 0.1, 0)
    norm = fit_normalizer(buf, train)
    steps = np.concatenate([np.arange(buf.episode_starts[e], buf.episode_ends[e]) for e in train])
    actions = norm.normalize("action", buf.action[steps])
    centres = kmeans(actions, 32, seed=0)
    err = np.sqrt(((actions[:, None] - centres[None]) ** 2).sum(-1)).min(1)
    assert err.mean() < 0.15, err.mean()  # 32 bins cover the 2-D workspace (normalised units)


def test_bet_attention_is_causal():
    torch.manual_seed(0)
    model = make_policy("bet", "quick", **tiny_overrides("bet")).eval()
    obs = _obs()
    changed = {k: v.clone() for k, v in obs.items()}
    changed["image"][:, 1] = torch.rand_like(changed["image"][:, 1])  # perturb the newest frame only
    with torch.no_grad():
        a, b = model.transformer(**obs), model.transformer(**changed)
    torch.testing.assert_close(a[:, 0], b[:, 0])  # the older token cannot see the newer one
    assert not torch.allclose(a[:, 1], b[:, 1])


def test_bct_queries_see_every_observation():
    torch.manual_seed(0)
    model = make_policy("bct", "quick", **tiny_overrides("bct")).eval()
    obs = _obs()
    changed = {k: v.clone() for k, v in obs.items()}
    changed["agent_pos"][:, 0] += 0.5  # perturb the *older* observation
    with torch.no_grad():
        a, b = model.predict_action_chunk(obs), model.predict_action_chunk(changed)
    assert a.shape == (2, 16, 2)
    assert (a - b).abs().amax(dim=-1).min() > 0  # every future step depends on it (no causal mask)


def test_bct_paper_size_within_one_percent():
    n = make_policy("bct", "paper").num_parameters()
    assert abs(n - STUDY_PARAMETERS["bct"]) / STUDY_PARAMETERS["bct"] < 0.01


def test_bet_checkpoint_keeps_kmeans_centres(synthetic_zarr, tmp_path):
    opts = TrainOptions(data=str(synthetic_zarr), threads=1, progress=False)
    run = new_run("bet", "quick", tiny_overrides("bet", max_steps=2), tmp_path / "bet", opts)
    centres = prepare(run, opts).model.centres.clone()
    assert centres.abs().sum() > 0  # fitted before training
    assert centres.min() >= -1 - 1e-5 and centres.max() <= 1 + 1e-5  # fitted on normalised actions
    train(run, opts)
    runner = load_runner(run)
    torch.testing.assert_close(runner.model.centres, centres)
    obs = {"image": np.zeros((2, 2, 96, 96, 3), np.uint8), "agent_pos": np.full((2, 2, 2), 200.0, np.float32)}
    assert runner.predict_action_chunk(obs).shape == (2, 16, 2)


@pytest.mark.parametrize("name", ["bet", "bct"])
def test_quick_presets_are_small(name):
    assert make_policy(name, "quick").num_parameters() < 3_000_000


def test_bet_weight_decay_skips_norms_biases_and_embeddings():
    from bcbench.policies.config import OptimConfig
    from bcbench.training.parts import make_optimizer

    model = make_policy("bet", "quick", **tiny_overrides("bet"))
    decay, no_decay = make_optimizer(model, OptimConfig(optimizer="adamw", weight_decay=0.1)).param_groups
    assert decay["weight_decay"] == 0.1 and no_decay["weight_decay"] == 0.0
    names = {id(p): n for n, p in model.named_parameters()}
    assert {names[id(p)] for p in no_decay["params"]} >= {"pos", "ln_f.weight", "ln_f.bias", "head.bias"}
    assert all(p.ndim >= 2 for p in decay["params"]) and "head.weight" in {names[id(p)] for p in decay["params"]}
    assert len(decay["params"]) + len(no_decay["params"]) == len(list(model.parameters()))
