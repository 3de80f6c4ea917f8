"""Run in the LeRobot sidecar (.lerobot-venv): save a randomly initialised LeRobot Diffusion Policy or ACT for
Push-T with its pre/post-processors, as `save_pretrained` and LeRobot's training script would.

    .lerobot-venv/bin/python tests/sidecar/make_random_lerobot.py {diffusion,act} OUT_DIR [--steps N]

Normalisation statistics are Push-T's ranges (agent and target positions in [0, 512] pixels); no weights are
downloaded (no ImageNet backbone).
"""

import argparse

import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.factory import get_policy_class, make_policy_config, make_pre_post_processors


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("kind", choices=["diffusion", "act"])
    ap.add_argument("out")
    ap.add_argument("--steps", type=int, default=10, help="diffusion: DDIM steps at inference")
    ap.add_argument("--small", action="store_true", help="diffusion: U-Net widths (64, 128, 256), for tests")
    args = ap.parse_args()
    torch.manual_seed(0)
    inputs = {"observation.image": PolicyFeature(FeatureType.VISUAL, (3, 96, 96)),
              "observation.state": PolicyFeature(FeatureType.STATE, (2,))}
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (2,))}
    # Diffusion Policy's Push-T windows (Chi et al. 2023): 2 observations, 16 actions, 8 executed, 84x84 crops.
    extra = ({"noise_scheduler_type": "DDIM", "num_inference_steps": args.steps, "horizon": 16, "n_action_steps": 8,
              "crop_shape": (84, 84), **({"down_dims": (64, 128, 256)} if args.small else {})}
             if args.kind == "diffusion" else {"chunk_size": 16, "n_action_steps": 8})
    cfg = make_policy_config(args.kind, input_features=inputs, output_features=outputs, device="cpu",
                             pretrained_backbone_weights=None, push_to_hub=False, **extra)
    policy = get_policy_class(args.kind)(cfg)
    lo, hi = torch.zeros(2), torch.full((2,), 512.0)
    stats = {"observation.state": {"min": lo, "max": hi, "mean": hi / 2, "std": hi / 4},
             "action": {"min": lo, "max": hi, "mean": hi / 2, "std": hi / 4},
             "observation.image": {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25),
                                   "min": torch.zeros(3, 1, 1), "max": torch.ones(3, 1, 1)}}
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    policy.save_pretrained(args.out)
    pre.save_pretrained(args.out)
    post.save_pretrained(args.out)
    print(args.out)


if __name__ == "__main__":
    main()
