"""What a scoring command runs: the policy of --policy or --checkpoint in its inference mode, the execution
strategy of the strategy options, and BID's weaker policy. Shared by `eval` and `realtime`."""

from __future__ import annotations

import argparse
from datetime import datetime
from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError
from bcbench.utils.io import safe_name


def backend(args: argparse.Namespace) -> str:
    """--backend, defaulted: auto (the fastest exact mode here) where a measured latency sets the delays, since
    the mode then changes the result; else torch, the reference every score can be reproduced with."""
    if args.backend is not None:
        return args.backend
    measured = getattr(args, "measured", False) or getattr(args, "latency", None) == "measured"
    return "auto" if measured and args.precision == "fp32" and not args.reference else "torch"


def _needs_torch(args: argparse.Namespace) -> str:
    """Why `auto` must stay in torch, or "": a sweep runs every strategy in one mode, so a sweep with rtc (whose
    guidance an exported graph cannot compute) times every strategy in torch's fast form."""
    from bcbench.evaluation.config import torch_only

    kinds = getattr(args, "strategy", None) or []
    return torch_only([kinds] if isinstance(kinds, str) else kinds, getattr(args, "rtc_jacobian", True))


def eval_namespace(**over: Any) -> argparse.Namespace:
    """The options `load_eval_policy` reads, as `bcbench eval` has them by default, with `over` in their place: how
    another command (choose, latency --checkpoint) resolves a policy exactly as `eval` does."""
    base = {"checkpoint": None, "policy": None, "policy_arg": None, "backend": None, "precision": "fp32",
            "reference": False, "sampler": None, "steps": None, "spacing": None, "preset": "quick", "seed": 0,
            "episodes": 1, "no_ema": False, "device": "cpu"}
    return argparse.Namespace(**{**base, **over})


def sampler_of(args: argparse.Namespace) -> tuple[str | None, int | None, str | None]:
    """(sampler, steps, spacing) a --checkpoint runs: as given; where none is given and the folder is a published
    model, the setting its committed score ran (model.json's scores: DDIM-10 for models/diffusion-cpu, not the
    run's own DDPM-100), so that `eval --checkpoint models/NAME` reproduces the number it is published with."""
    given = (args.sampler, args.steps, args.spacing)
    if any(v is not None for v in given):
        return given
    from bcbench.analysis.published import model_record

    scores = (model_record(args.checkpoint) or {}).get("scores") or {}
    return scores.get("sampler"), scores.get("steps"), scores.get("spacing")


def load_eval_policy(args: argparse.Namespace) -> tuple[Any, Path]:
    """The policy to evaluate and the default output folder."""
    from bcbench.policies import REGISTRY, is_learned, make_policy
    from bcbench.policies.outside import outside_policy, parse_kwargs
    from bcbench.tasks import DEFAULT_TASK, get_task

    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    if args.checkpoint:
        from bcbench.evaluation.backends import apply_mode
        from bcbench.modes import mode_name
        from bcbench.policies.checkpoint import configure_runner, load_runner

        runner = load_runner(args.checkpoint, use_ema=not args.no_ema, device=args.device)
        sampler, steps, spacing = sampler_of(args)
        tag = configure_runner(runner, sampler, steps, args.seed, spacing)
        mode = mode_name(backend(args), args.precision, args.reference)
        apply_mode(runner, mode, torch_only=_needs_torch(args))
        tag += "" if mode == "fast" else f"{mode}-"
        return runner, Path(args.checkpoint) / f"eval-{tag}{args.episodes}ep-{stamp}"
    if not args.policy:
        raise BCBenchError("choose --policy NAME or --checkpoint RUN_DIR")
    if args.backend not in (None, "torch") or args.precision != "fp32" or args.reference:
        raise BCBenchError("--backend/--precision/--reference apply to a trained --checkpoint")
    if args.sampler or args.steps or args.spacing:
        raise BCBenchError("--sampler/--steps/--spacing need a diffusion --checkpoint")
    if is_learned(args.policy):
        raise BCBenchError(f"'{args.policy}' is a learned policy: train it (`bcbench train --policy {args.policy}`) "
                           "and evaluate with --checkpoint RUN_DIR")
    if args.policy in REGISTRY:
        if args.policy_arg:
            raise BCBenchError("--policy-arg goes with an outside policy (module:factory or a plug-in)")
        task = get_task(getattr(args, "task", None) or DEFAULT_TASK)
        return make_policy(args.policy, args.preset, task, seed=args.seed), Path("runs") / f"eval-{args.policy}-{stamp}"
    policy = outside_policy(args.policy, parse_kwargs(args.policy_arg))  # checked before anything runs
    return policy, Path("runs") / f"eval-{safe_name(policy.name)}-{stamp}"


def strategy_config(args: argparse.Namespace, kind: str, several: bool = False) -> Any:
    """The StrategyConfig of the command line's strategy options, for strategy `kind` (`several`: one of a sweep's
    strategies, where --bid-weak belongs to bid alone)."""
    from bcbench.evaluation.config import StrategyConfig

    return StrategyConfig(kind, args.rtc_max_guidance, args.rtc_jacobian, args.bid_samples, args.bid_modes,
                          args.bid_weak if kind == "bid" or not several else None, args.ensemble_decay,
                          args.correction if kind == "correction" or not several else None)


def load_head(args: argparse.Namespace) -> Any:
    """A2C2's correction head (--correction RUN_DIR), in torch on the policy's device (it is small; its base's
    encoder runs beside the policy's graphs); checked against the policy by the strategy."""
    if not args.correction:
        return None
    if not args.checkpoint:
        raise BCBenchError("--correction goes with the trained --checkpoint it was trained on")
    from bcbench.policies.checkpoint import load_correction

    return load_correction(args.correction, device=args.device)


def load_weak(args: argparse.Namespace, policy: Any) -> Any:
    """BID's weaker policy (--bid-weak RUN_DIR), run as the policy is: same sampler, seed and inference mode."""
    if not args.bid_weak:
        return None
    if not args.checkpoint:
        raise BCBenchError("--bid-weak goes with a trained --checkpoint")
    from bcbench.evaluation.backends import apply_mode
    from bcbench.modes import mode_name
    from bcbench.policies.checkpoint import configure_runner, load_runner

    weak = load_runner(args.bid_weak, use_ema=not args.no_ema, device=args.device)
    if weak.name != policy.name:
        raise BCBenchError(f"--bid-weak is a {weak.name} run; the policy is {policy.name}")
    configure_runner(weak, policy.info.sampler, policy.info.steps, args.seed, policy.info.spacing)  # as the policy
    apply_mode(weak, policy.info.mode or mode_name(backend(args), args.precision, args.reference))
    return weak


def measured_sources(policy: Any, built: dict[str, Any]) -> dict[str, Any]:
    """Each strategy's measured latency, its request timed in interleaved rounds with the others' before any
    episode, so that no strategy's delays come from a quieter moment of the machine than another's."""
    from statistics import median

    from bcbench.evaluation.latency_sources import LatencySource, interleaved_request_ms

    rounds, contention = interleaved_request_ms(policy, built)
    measured = {k: LatencySource("measured", samples_ms=[ms for r in rs for ms in r], contention=contention)
                for k, rs in rounds.items()}
    print(f"measured latency, each strategy's request timed in {len(next(iter(rounds.values())))} interleaved rounds "
          "before any episode: " + ", ".join(f"{k} {median(v.samples_ms):.1f} ms" for k, v in measured.items()))
    return measured
