"""Diffusion Policy: exact sizes, FiLM conditioning, sampler equivalence with diffusers, any step count."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from bcbench.policies import make_policy
from bcbench.policies.diffusion import DiffusionConfig
from bcbench.policies.samplers import (
    make_diffusers_sampler,
    make_train_scheduler,
    plan,
    run_diffusers,
    run_plan,
    spaced_timesteps,
)
from bcbench.policies.unet1d import ConditionalResidualBlock1D, ConditionalUnet1D, Conv1d, UpConv1d
from bcbench.reference import DIFFUSION_PARAMETERS as STUDY_PARAMETERS
from tests.tiny import tiny_overrides


@pytest.fixture(scope="module")
def tiny():
    torch.manual_seed(0)
    return make_policy("diffusion", "quick", **tiny_overrides("diffusion")).eval()


def _obs(b: int = 3) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(1)
    return {"image": torch.rand(b, 2, 3, 96, 96, generator=g), "agent_pos": torch.rand(b, 2, 2, generator=g) * 2 - 1}


def test_paper_size_matches_the_study_exactly():
    counts = make_policy("diffusion", "paper").parameter_breakdown()
    assert counts == {"encoder": STUDY_PARAMETERS["encoder"], "unet": STUDY_PARAMETERS["unet"],
                      "total": STUDY_PARAMETERS["total"]}


def test_film_conditioning_changes_the_output():
    torch.manual_seed(0)
    block = ConditionalResidualBlock1D(4, 8, cond_dim=6, kernel=5, groups=4)
    x = torch.randn(2, 4, 16)
    a, b = block(x, torch.zeros(2, 6)), block(x, torch.ones(2, 6))
    assert not torch.allclose(a, b, atol=1e-4)
    unet = ConditionalUnet1D(2, global_cond_dim=10, step_embed_dim=8, down_dims=(8, 16, 32), groups=4)
    s, t = torch.randn(2, 16, 2), torch.tensor([3, 3])
    assert unet(s, t, torch.zeros(2, 10)).shape == (2, 16, 2)
    assert not torch.allclose(unet(s, t, torch.zeros(2, 10)), unet(s, t, torch.randn(2, 10)), atol=1e-4)
    assert not torch.allclose(unet(s, t, torch.zeros(2, 10)), unet(s, t + 40, torch.zeros(2, 10)), atol=1e-4)


@pytest.mark.parametrize("spacing", ["trailing", "leading"])
@pytest.mark.parametrize("kind", ["ddpm", "ddim"])
@pytest.mark.parametrize("steps", [1, 3, 10, 37, 100])
def test_sampler_matches_diffusers_reference_loop(tiny, kind, steps, spacing):
    """Our precomputed constants against diffusers' scheduler configured with the same spacing, same noise."""
    tiny.set_sampler(kind, steps, spacing)
    with torch.no_grad():
        cond = tiny.encode(**_obs())

        def denoise(x, t):
            return tiny.unet(x, torch.tensor(t), cond)

        x0 = torch.randn(3, 16, 2, generator=torch.Generator().manual_seed(7))
        g = torch.Generator().manual_seed(9)
        ours = run_plan(tiny.plan, denoise, x0.clone(), lambda shape: torch.randn(shape, generator=g))
        sched = make_diffusers_sampler(tiny.noise_scheduler, kind, steps, spacing)
        assert [int(t) for t in sched.timesteps] == tiny.plan.timesteps
        ref = run_diffusers(sched, denoise, x0.clone(), torch.Generator().manual_seed(9))
    torch.testing.assert_close(ours, ref, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("kind", ["ddpm", "ddim"])
def test_trailing_spacing_starts_every_step_count_from_pure_noise(kind):
    sched = make_train_scheduler(100, "squaredcos_cap_v2")
    for k in range(1, 101):
        p = plan(sched, kind, k, "trailing")
        assert p.timesteps[0] == 99 and len(p.timesteps) == k, k
        assert p.timesteps == sorted(p.timesteps, reverse=True) and len(set(p.timesteps)) == k
    assert plan(sched, kind, 10, "trailing").timesteps[-1] == 9
    # leading, diffusers' default, does not: K=1 starts at t=0 (no noise at all), K=40 at t=78
    assert plan(sched, kind, 1, "leading").timesteps == [0] and plan(sched, kind, 40, "leading").timesteps[0] == 78


@pytest.mark.parametrize("kind", ["ddpm", "ddim"])
def test_one_step_from_pure_noise_returns_the_x0_estimate(tiny, kind):
    """At K = 1 (trailing) the single step predicts x0 from t = 99 and lands on it: not clipped noise."""
    tiny.set_sampler(kind, 1, "trailing")
    with torch.no_grad():
        cond = tiny.encode(**_obs())
        x = torch.randn(3, 16, 2, generator=torch.Generator().manual_seed(7))
        eps = tiny.unet(x, torch.tensor(99), cond)
        ac = tiny.noise_scheduler.alphas_cumprod[99]
        x0_hat = ((x - (1 - ac).sqrt() * eps) / ac.sqrt()).clamp(-1, 1)
        out = run_plan(tiny.plan, lambda x, t: tiny.unet(x, torch.tensor(t), cond), x.clone(), torch.randn)
    torch.testing.assert_close(out, x0_hat, atol=1e-5, rtol=1e-5)
    assert not torch.allclose(out, x.clamp(-1, 1), atol=1e-2)


@pytest.mark.parametrize("kind", ["ddpm", "ddim"])
@pytest.mark.parametrize("steps", [1, 2, 7, 33, 100])
def test_any_step_count_gives_valid_chunks(tiny, kind, steps):
    tiny.set_sampler(kind, steps)
    tiny.reset_noise(0)
    with torch.no_grad():
        chunk = tiny.predict_action_chunk(_obs())
    assert chunk.shape == (3, 16, 2) and torch.isfinite(chunk).all()
    assert chunk.abs().max() <= 1.0 + 1e-6  # normalised action range
    assert len(tiny.plan.timesteps) == steps


def test_seeded_inference_is_reproducible(tiny):
    tiny.set_sampler("ddpm", 5)
    tiny.reset_noise(3)
    with torch.no_grad():
        a = tiny.predict_action_chunk(_obs())
        tiny.reset_noise(3)
        b = tiny.predict_action_chunk(_obs())
    torch.testing.assert_close(a, b)


@pytest.mark.parametrize("beta_schedule", ["squaredcos_cap_v2", "linear"])
@pytest.mark.parametrize("n", [100, 7])
def test_own_noise_schedule_and_timesteps_equal_diffusers_bit_for_bit(n, beta_schedule):
    """bcbench computes DDPM's noise levels and the visited timesteps itself (diffusers costs seconds to import):
    every tensor and every timestep list equals diffusers' own, for every K, sampler and spacing."""
    ours = make_train_scheduler(n, beta_schedule)
    ref = make_diffusers_sampler(ours, "ddpm", n)  # diffusers' own scheduler, built from the schedule's settings only
    assert torch.equal(ours.betas, ref.betas) and torch.equal(ours.alphas_cumprod, ref.alphas_cumprod)
    for kind in ("ddpm", "ddim"):
        for spacing in ("trailing", "leading"):
            for k in range(1, n + 1):
                want = [int(t) for t in make_diffusers_sampler(ours, kind, k, spacing).timesteps]
                assert spaced_timesteps(n, k, spacing) == want == plan(ours, kind, k, spacing).timesteps, (kind, k)


def test_building_and_sampling_a_diffusion_policy_does_not_import_diffusers():
    import subprocess
    import sys

    code = ("import sys, torch\n"
            "from bcbench.policies import make_policy\n"
            "from tests.tiny import tiny_overrides\n"
            "m = make_policy('diffusion', 'quick', **tiny_overrides('diffusion')).eval()\n"
            "m.set_sampler('ddpm', 3, 'leading')\n"
            "obs = {'image': torch.rand(1, 2, 3, 96, 96), 'agent_pos': torch.rand(1, 2, 2)}\n"
            "with torch.no_grad():\n"
            "    m.predict_action_chunk(obs)\n"
            "print('diffusers' in sys.modules)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          cwd=str(Path(__file__).parents[1]))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "False"


def test_linear_beta_config():
    cfg = DiffusionConfig.preset("quick_linear")
    assert cfg.beta_schedule == "linear" and DiffusionConfig.preset("paper_linear").beta_schedule == "linear"
    model = make_policy("diffusion", "quick_linear", **tiny_overrides("diffusion"))
    betas = model.noise_scheduler.betas
    assert betas[0].item() == pytest.approx(1e-4) and betas[-1].item() == pytest.approx(0.02)
    cosine = make_policy("diffusion", "quick", **tiny_overrides("diffusion")).noise_scheduler.betas
    assert not torch.allclose(betas, cosine)
    batch = {**_obs(4), "action": torch.rand(4, 16, 2) * 2 - 1}
    assert torch.isfinite(model.train().compute_loss(batch))


def test_eval_with_sampler_from_a_checkpoint(synthetic_zarr, tmp_path):
    from bcbench.cli.main import main  # in-process: a subprocess per command cost this test 40 s of start-up

    run = tmp_path / "dp"
    sets = [a for k, v in tiny_overrides("diffusion", max_steps=2).items() for a in ("--set", f"{k}={json.dumps(v)}")]
    assert main(["train", "--policy", "diffusion", "--out", str(run), "--data", str(synthetic_zarr), "--quiet",
                 *sets]) == 0
    assert main(["eval", "--checkpoint", str(run), "--sampler", "ddim", "--steps", "3", "--episodes", "2",
                 "--max-steps", "8", "--out", str(tmp_path / "ev"), "--quiet"]) == 0
    policy = json.loads((tmp_path / "ev" / "eval.json").read_text())["policy"]
    assert policy["sampler"] == "ddim" and policy["steps"] == 3 and policy["weights"] == "ema"


# ----------------------------------------------------------------------------- flow matching (same network)


@pytest.fixture(scope="module")
def tiny_flow():
    torch.manual_seed(0)
    return make_policy("flow", "quick", **tiny_overrides("flow")).eval()


@pytest.mark.parametrize("preset", ["quick", "cpu", "paper"])
def test_flow_has_diffusions_parameter_count(preset):
    assert make_policy("flow", preset).num_parameters() == make_policy("diffusion", preset).num_parameters()


def test_flow_loss_decreases_on_a_tiny_batch():
    torch.manual_seed(0)
    model = make_policy("flow", "quick", **tiny_overrides("flow")).train()
    batch = {**_obs(8), "action": torch.rand(8, 16, 2) * 2 - 1}
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(30):
        torch.manual_seed(1)  # the same noise and times every step: a fixed regression target
        loss = model.compute_loss(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]


@pytest.mark.parametrize("kind, calls_per_step", [("euler", 1), ("midpoint", 2)])
@pytest.mark.parametrize("steps", [1, 2, 4])
def test_flow_sampling_calls_and_determinism(tiny_flow, kind, steps, calls_per_step, monkeypatch):
    tiny_flow.set_sampler(kind, steps)
    calls = {"n": 0}
    real = tiny_flow.unet.forward_film  # the denoising graph: one U-Net evaluation

    def counted(*a, **k):
        calls["n"] += 1
        return real(*a, **k)

    monkeypatch.setattr(tiny_flow.unet, "forward_film", counted)
    with torch.no_grad():
        tiny_flow.reset_noise(5)
        a = tiny_flow.predict_action_chunk(_obs())
        tiny_flow.reset_noise(5)
        b = tiny_flow.predict_action_chunk(_obs())
    assert calls["n"] == 2 * steps * calls_per_step  # K = 1 Euler is one network call
    torch.testing.assert_close(a, b)
    assert a.shape == (3, 16, 2) and a.abs().max() <= 1.0


def test_flow_one_euler_step_is_noise_plus_velocity(tiny_flow):
    tiny_flow.set_sampler("euler", 1)
    with torch.no_grad():
        obs = _obs()
        tiny_flow.reset_noise(2)
        out = tiny_flow.predict_action_chunk(obs)
        tiny_flow.reset_noise(2)
        noise = tiny_flow.randn(obs, (3, 16, 2), torch.device("cpu"))
        v = tiny_flow.velocity(noise, torch.zeros(3), tiny_flow.encode(obs["image"], obs["agent_pos"]))
    torch.testing.assert_close(out, (noise + v).clamp(-1, 1))


def test_flow_rejects_diffusion_options(tiny_flow):
    from bcbench.errors import BCBenchError

    with pytest.raises(BCBenchError, match="euler or midpoint"):
        tiny_flow.set_sampler("ddim", 10)
    with pytest.raises(BCBenchError, match="spacing"):
        tiny_flow.set_sampler("euler", 2, "leading")


@pytest.mark.parametrize("cin,cout,k,stride,t", [(4, 6, 5, 1, 8), (3, 5, 3, 2, 8), (6, 2, 1, 1, 4), (4, 4, 5, 1, 16),
                                                 (600, 7, 5, 1, 16)])
def test_conv1d_equals_the_convolution_with_gradients(cin, cout, k, stride, t):
    """The U-Net's Conv1d (im2col + matmul for wide layers, else oneDNN's convolution) gives the convolution's
    output and the same input and weight gradients."""
    torch.manual_seed(0)
    conv = Conv1d(cin, cout, k, stride, k // 2).train()
    x = torch.randn(5, cin, t, requires_grad=True)
    got = conv(x)
    want = torch.nn.functional.conv1d(x, conv.weight, conv.bias, stride, k // 2)
    assert got.shape == want.shape and torch.allclose(got, want, atol=1e-4)
    grad = torch.randn_like(want)
    g_got = torch.autograd.grad(got, [x, conv.weight, conv.bias], grad)
    g_want = torch.autograd.grad(want, [x, conv.weight, conv.bias], grad)
    assert all(torch.allclose(a, b, atol=1e-3) for a, b in zip(g_got, g_want, strict=True))


@pytest.mark.parametrize("cin,cout,k,stride,t", [(4, 6, 5, 1, 8), (3, 5, 3, 2, 8), (6, 2, 1, 1, 4), (5, 5, 3, 2, 7)])
def test_conv1d_time_last_form_equals_the_convolution(cin, cout, k, stride, t):
    """The channels-last matrix form the exporters trace gives the convolution's output."""
    torch.manual_seed(0)
    conv = Conv1d(cin, cout, k, stride, k // 2)
    x = torch.randn(3, cin, t)
    want = torch.nn.functional.conv1d(x, conv.weight, conv.bias, stride, k // 2)  # (B, Cout, T')
    torch.testing.assert_close(conv.forward_time_last(x.transpose(1, 2)), want.transpose(1, 2), atol=1e-5, rtol=0)


@pytest.mark.parametrize("t", [1, 4, 8])
def test_upconv_time_last_form_equals_the_transposed_convolution(t):
    torch.manual_seed(0)
    up = UpConv1d(6)
    x = torch.randn(2, 6, t)
    want = torch.nn.functional.conv_transpose1d(x, up.weight, up.bias, 2, 1)  # (B, C, 2T)
    torch.testing.assert_close(up.forward_time_last(x.transpose(1, 2)), want.transpose(1, 2), atol=1e-5, rtol=0)


@pytest.mark.parametrize("batch", [1, 3])
def test_unet_time_last_form_equals_channels_first(batch):
    """forward_film's channels-last form (the exported graph) equals the torch form, GroupNorm's affine
    parameters and every bias perturbed so a dropped term would show."""
    torch.manual_seed(0)
    unet = ConditionalUnet1D(2, 10, 16, (8, 16, 32), 5, 4).eval()
    with torch.no_grad():
        for p in unet.parameters():
            p.add_(torch.randn_like(p) * 0.1)
        x, film = torch.randn(batch, 16, 2), torch.randn(batch, unet.obs_film(torch.randn(1, 10)).shape[-1])
        want = unet.forward_film(x, film)
        got = unet.forward_film(x, film, time_last=True)
    assert want.abs().max() > 0.1
    torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)
