"""Every learned policy in the registry, at a tiny size: construction, shapes, learning, round trip."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bcbench.data import MinMaxNormalizer
from bcbench.policies import REGISTRY, learned_policies, make_config, make_policy
from bcbench.policies.config import config_from_dict, config_to_dict
from bcbench.policies.encoders import resnet18, resnet50
from bcbench.policies.learned import PolicyRunner
from tests.tiny import TINY, tiny_overrides

LEARNED = learned_policies()


def _batch(b: int = 4, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {"image": torch.rand(b, 2, 3, 96, 96, generator=g), "agent_pos": torch.rand(b, 2, 2, generator=g) * 2 - 1,
            "action": torch.rand(b, 16, 2, generator=g) * 2 - 1}


def test_every_learned_policy_has_a_tiny_config():
    assert set(LEARNED) <= set(TINY), "add a tiny config for each new policy in tests/tiny.py"


@pytest.mark.parametrize("name", LEARNED)
def test_presets_construct_and_roundtrip_json(name):
    for preset in ("quick", "paper"):
        cfg = make_config(name, preset)
        again = config_from_dict(REGISTRY[name][0], config_to_dict(cfg))
        assert again == cfg


@pytest.mark.parametrize("name", LEARNED)
def test_chunk_shape_and_loss(name):
    torch.manual_seed(0)
    model = make_policy(name, "quick", **tiny_overrides(name)).eval()
    batch = _batch()
    with torch.no_grad():
        chunk = model.predict_action_chunk(batch)
    assert chunk.shape == (4, 16, 2) and torch.isfinite(chunk).all()
    assert model.compute_loss(batch).ndim == 0


@pytest.mark.parametrize("name", LEARNED)
def test_loss_decreases_on_one_tiny_batch(name):
    torch.manual_seed(0)
    model = make_policy(name, "quick", **tiny_overrides(name)).train()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    batch = _batch()
    losses = []
    for _ in range(80):
        loss = model.compute_loss(batch)
        losses.append(loss.item())
        opt.zero_grad()
        loss.backward()
        opt.step()
    # means over 10 steps: diffusion losses are noisy (random timestep and noise each step) and the
    # epsilon-prediction loss has a floor well above zero, hence the modest factor
    first, last = sum(losses[:10]) / 10, sum(losses[-10:]) / 10
    assert last < 0.8 * first, (first, last)


@pytest.mark.parametrize("name", LEARNED)
def test_runner_maps_raw_observations_to_pixels(name):
    torch.manual_seed(0)
    model = make_policy(name, "quick", **tiny_overrides(name))
    norm = MinMaxNormalizer.fit({"agent_pos": np.array([[0.0, 0.0], [512.0, 512.0]]),
                                 "action": np.array([[10.0, 20.0], [500.0, 490.0]])})
    runner = PolicyRunner(model, norm)
    obs = {"image": np.zeros((2, 2, 96, 96, 3), np.uint8), "agent_pos": np.full((2, 2, 2), 256.0, np.float32)}
    chunk = runner.predict_action_chunk(obs)
    assert chunk.shape == (2, 16, 2) and chunk.dtype == np.float32
    assert runner.chunk_start == 1 and runner.describe()["parameters"] == model.num_parameters()
    model.reset_noise(7)  # `--seed 7`: a replicate of the same checkpoint, told apart in its record
    assert runner.describe()["noise_seed"] == 7


@pytest.mark.parametrize("make, norm", [(resnet18, "group"), (resnet50, "batch")])
@pytest.mark.parametrize("bf16", [False, True])
def test_resnet_stem_relu_after_pool_keeps_values_and_gradients(make, norm, bf16):
    """The stem runs ReLU after the max-pool (faster): it must equal the textbook order bit for bit, forward and
    backward, also in bf16, where ties inside a pooling window are frequent."""
    torch.manual_seed(0)
    net = make(norm, width=16, layers=(1, 1))
    x = torch.randn(4, 3, 40, 40)

    def textbook(x: torch.Tensor) -> torch.Tensor:
        y = net.maxpool(net.relu(net.bn1(net.conv1(x))))
        return net.layer2(net.layer1(y))

    outs = []
    for fn in (net, textbook):
        with torch.autocast("cpu", torch.bfloat16, enabled=bf16):
            out = fn(x)
        outs.append((out, torch.autograd.grad(out.float().square().sum(), list(net.parameters()))))
    (out, grads), (ref, ref_grads) = outs
    assert torch.equal(out, ref)
    assert all(torch.equal(a, b) for a, b in zip(grads, ref_grads, strict=True))


@pytest.mark.parametrize("channels_last_input", [False, True])
def test_time_merge_equals_the_3d_convolution_and_stays_channels_last(channels_last_input):
    """TimeMerge computes the study's 3-D convolution as a 2-D one over stacked frames, channels-last (the
    layout of every later convolution; a (B, C, H, W) output cost the CNN-MLP and ResNet-50 trainers time)."""
    from torch.nn import functional as F

    from bcbench.policies.regressor import TimeMerge

    torch.manual_seed(0)
    merge = TimeMerge(obs_horizon=2, out_channels=8).eval()
    merge.bn.running_mean.uniform_(-0.5, 0.5)
    merge.bn.running_var.uniform_(0.5, 2.0)
    image = torch.rand(3, 2, 3, 20, 20)  # (B, To, C, H, W)
    if channels_last_input:  # an image that arrives in another layout gives the same numbers
        image = image.contiguous(memory_format=torch.channels_last_3d)
    out = merge(image)  # (B, C, H, W)
    reference = F.relu(merge.bn(merge.conv(image.transpose(1, 2)).squeeze(2)))  # Conv3d over (B, C, To, H, W)
    assert out.shape == (3, 8, 20, 20)
    assert out.is_contiguous(memory_format=torch.channels_last)
    torch.testing.assert_close(out, reference, rtol=0, atol=1e-5)
