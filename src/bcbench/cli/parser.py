"""The `bcbench` command line's arguments: one parser per command group, validated types, one-line errors.

Each subcommand names its handler (`func`, a `bcbench.cli.main.cmd_*` function) by name, so this module does not
import the commands (nor torch, nor the policies) to build the parser, and neither do the modules it reads:
`bcbench.cli.parser_data` (the `data` commands) and `bcbench.cli.options` (the option helpers). Options that fill a
config take their default and help from that config's field (`_field`): written once, in the dataclass.
"""

from __future__ import annotations

import argparse
from typing import Any

from bcbench import __version__
from bcbench.cli.options import (
    _add_data_flag,
    _add_task_flag,
    _field,
    _nonneg_int,
    _number,
    _positive_float,
    _positive_int,
)
from bcbench.cli.parser_data import _add_data_commands
from bcbench.evaluation.config import EXECUTIONS, STRATEGIES, EvalConfig, StrategyConfig, WallClockConfig
from bcbench.modes import BACKENDS, MODES, PRECISIONS
from bcbench.training.options import TrainOptions
from bcbench.utils.args import OneLineParser
from bcbench.utils.fields import field_docs


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="bcbench", description=__doc__.split("\n")[0] if __doc__ else None)
    parser.description = ("Train, evaluate and benchmark visuomotor behavior-cloning policies on Push-T and "
                          "MetaWorld tasks (--task): task accuracy against real-time inference latency.")
    parser.add_argument("--version", action="version", version=f"bcbench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    sub.required = True

    _add_data_commands(sub)
    _add_train_eval_commands(sub)
    _add_study_commands(sub)
    _add_deploy_commands(sub)
    return parser


def _add_train_eval_commands(sub: Any) -> None:
    p = sub.add_parser("train", help="train a policy (resumable; checkpoints, metrics.jsonl)")
    p.add_argument("--policy", metavar="NAME", help="learned policy to train (`bcbench policies` lists them)")
    p.add_argument("--preset", "--config", dest="preset", default="quick",
                   help="quick (minutes on a 2-core CPU), cpu (the CPU study's recipes, chosen on validation seeds; "
                        "each one's 2x convergence check: docs/results.md) or paper (the "
                        "study's sizes); diffusion also has quick_linear, cpu_linear, paper_linear (linear betas). "
                        "--config is the old name of this option")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a config field, e.g. --set optim.epochs=2 --set hidden=64 (repeatable)")
    _field(p, "--max-minutes", TrainOptions, type=_positive_float, metavar="M")
    p.add_argument("--out", metavar="DIR", help="run directory (default runs/train-POLICY-CONFIG-TIME)")
    p.add_argument("--resume", metavar="RUN_DIR", help="continue a run from its newest checkpoint")
    p.add_argument("--pretrained", metavar="PATH", help="torchvision-format ImageNet weights (local file)")
    p.add_argument("--seed", type=_nonneg_int, help="seed (default: the config's, 0)")
    p.add_argument("--precision", choices=["auto", "fp32", "bf16"],
                   help="forward-pass precision (default: the config's, auto = bf16 autocast where the hardware "
                        "computes bf16 natively, else fp32)")
    _field(p, "--eval-every", TrainOptions, type=_positive_int, metavar="STEPS")
    _field(p, "--eval-episodes", TrainOptions, type=_positive_int, metavar="N")
    _field(p, "--demos", TrainOptions, type=_positive_int, metavar="N")
    _field(p, "--threads", TrainOptions, type=_positive_int)
    _field(p, "--device", TrainOptions, choices=["auto", "cpu", "cuda"])
    _add_task_flag(p)
    _add_data_flag(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func="cmd_train")
    _add_eval_command(sub)


def _add_study_commands(sub: Any) -> None:
    p = sub.add_parser("study", help="run a study spec: train, evaluate and time every run (resumable)")
    p.add_argument("spec", metavar="SPEC.toml", help="study specification (see studies/)")
    p.add_argument("--out", metavar="DIR", help="results directory (default runs/studies/NAME)")
    p.add_argument("--check", action="store_true", help="validate the spec and exit")
    p.add_argument("--status", action="store_true", help="where the study in --out stands (stages done, each "
                   "training's step, rate and time left), read from its files; starts nothing")
    p.add_argument("--no-report", action="store_true", help="do not write the report at the end")
    p.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS",
                   help="run the stages as Ray tasks: alone = a local Ray instance; 'auto' or HOST:PORT = a "
                        "cluster (its nodes need resources bcbench_node=1000; see bcbench.study.on_ray)")
    p.add_argument("--ray-cpus", type=_positive_int, metavar="N", help="CPUs of the local Ray instance (default all)")
    p.add_argument("--task", metavar="NAME", help="run the spec on this task instead of its study.task (pusht or "
                   "metaworld/NAME)")
    _add_data_flag(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func="cmd_study")

    p = sub.add_parser("report", help="Markdown + HTML report with the study's figures, from result files only")
    p.add_argument("results", metavar="RESULTS_DIR", help="a study's results directory")
    p.add_argument("--include", action="append", metavar="DIR",
                   help="also read result JSON files from this folder (e.g. results/ from a GPU machine)")
    p.add_argument("--export", metavar="DIR", help="also copy the result files (no checkpoints) to DIR")
    p.set_defaults(func="cmd_report")

    _add_latency_command(sub)
    _add_realtime_command(sub)
    _add_choose_command(sub)
    _add_serve_command(sub)

    p = sub.add_parser("params", help="parameter counts of every learned policy (paper and quick sizes)")
    _add_task_flag(p)
    p.set_defaults(func="cmd_params")

    p = sub.add_parser("policies", help="the policies bcbench can run: built in, installed plug-ins, module:factory")
    p.set_defaults(func="cmd_policies")


def _add_latency_command(sub: Any) -> None:
    p = sub.add_parser("latency", help="time one policy call at batch 1 for every policy, in every inference mode")
    p.add_argument("--policy", action="append", metavar="NAME", help="only these policies (repeatable; default all "
                   "built-in): registered names, plug-ins or module:factory (`bcbench policies`)")
    _add_policy_arg(p)
    p.add_argument("--preset", "--config", dest="preset", action="append", choices=["quick", "cpu", "paper"],
                   help="presets (default paper and quick; --config is the old name of this option)")
    p.add_argument("--checkpoint", action="append", metavar="RUN_DIR",
                   help="time this trained run or published model (e.g. models/diffusion-cpu; repeatable) in its "
                        "own setting (a published model's recorded sampler and steps unless --sampler/--steps), "
                        "instead of the untrained registry policies")
    p.add_argument("--backend", "--mode", dest="mode", action="append", choices=[*MODES, *BACKENDS],
                   metavar="BACKEND",
                   help="inference modes (repeatable): a mode (reference, fast, openvino-fp32|bf16|int8|int8w, "
                        "onnxruntime-fp32|int8) or a backend as `eval --backend` takes it (torch = fast, openvino = "
                        "openvino-fp32, onnxruntime = onnxruntime-fp32, auto: the fastest exact one on this machine, "
                        "measured, as a user gets it). Default: every mode and auto (a --checkpoint: the exact "
                        "ones and auto). --mode is the old name of this option")
    p.add_argument("--sampler", action="append", choices=["ddpm", "ddim", "euler", "midpoint"],
                   help="samplers of generative policies (default ddpm and ddim; flow: euler)")
    p.add_argument("--steps", type=_positive_int, action="append",
                   help="diffusion step counts (default 1 2 5 10 20 50 100)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"], help="default auto")
    p.add_argument("--threads", type=_positive_int, help="torch threads (default: torch's choice)")
    p.add_argument("--rate", type=_positive_float, help="control rate for the verdicts, Hz (default: the task's, "
                   "Push-T's 10)")
    _add_task_flag(p, trained=True)
    p.add_argument("--quick", action="store_true", help="fewer timed calls (a rough table in a minute or two)")
    p.add_argument("--out", metavar="DIR", help="output folder (default runs/latency-TIME)")
    p.set_defaults(func="cmd_latency")


def _add_choose_command(sub: Any) -> None:
    p = sub.add_parser("choose", help="which policy for my control loop, on this machine: every published model "
                       "timed here, re-scored on a few test episodes, read at the delay its latency implies")
    p.add_argument("--models", default="models", metavar="DIR",
                   help="the published models (default models/ of the repository)")
    p.add_argument("--results", default="results", metavar="DIR",
                   help="the committed results whose real-time sweeps are read (default results/)")
    p.add_argument("--policy", action="append", metavar="NAME",
                   help="also a policy of yours (repeatable): a plug-in (knn), module:factory or lerobot:FOLDER, as "
                        "`bcbench eval --policy` takes it; it is scored live on --episodes test seeds")
    _add_policy_arg(p)
    p.add_argument("--rate", type=_positive_float, default=10.0, metavar="HZ",
                   help="the control loop's rate in Hz (default 10)")
    p.add_argument("--episodes", type=_positive_int, default=5, metavar="N",
                   help="test episodes re-scored live per policy (default 5)")
    p.add_argument("--calls", type=_positive_int, default=100, metavar="N",
                   help="timed calls per policy and mode (default 100: a p99; fewer: the maximum, labelled)")
    p.add_argument("--threads", type=_positive_int, help="torch threads (default: torch's choice)")
    p.add_argument("--no-video", action="store_true", help="no rollout video of the chosen policy")
    p.add_argument("--out", default="runs/choose", metavar="DIR", help="the page's folder (default runs/choose)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func="cmd_choose")


def _add_policy_source_args(p: argparse.ArgumentParser) -> None:
    """Which policy a command runs: a baseline, plug-in or module:factory, or a trained run with its sampler setting
    (realtime and serve take the same)."""
    p.add_argument("--policy", metavar="NAME", help="a baseline, a plug-in or module:factory (or --checkpoint)")
    _add_policy_arg(p)
    p.add_argument("--preset", "--config", dest="preset", default="quick", help=argparse.SUPPRESS)
    p.add_argument("--checkpoint", metavar="RUN_DIR", help="a trained run")
    p.add_argument("--sampler", choices=["ddpm", "ddim", "euler", "midpoint"], help="generative policies: sampler")
    p.add_argument("--steps", type=_positive_int, help="generative policies: steps")
    p.add_argument("--spacing", choices=["trailing", "leading"], help="diffusion: timestep spacing")


def _add_realtime_command(sub: Any) -> None:
    p = sub.add_parser("realtime", help="score under real-time execution: against delay, at measured latency, "
                       "under a hardware profile")
    _add_policy_source_args(p)
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help=argparse.SUPPRESS)
    p.add_argument("--seed", type=_nonneg_int, default=0, help="the policy's own random seed (default 0)")
    p.add_argument("--delays", type=_nonneg_int, nargs="+", default=[0, 1, 2, 4, 8], metavar="D",
                   help="delays in control steps of 0.1 s (default 0 1 2 4 8)")
    p.add_argument("--execution", nargs="+", default=["blocking", "async"], choices=["blocking", "async"],
                   help="execution modes under latency (default both; sync is always run as d = 0)")
    p.add_argument("--profile", action="append", help="also under this hardware profile (e.g. a100)")
    p.add_argument("--measured", action="store_true",
                   help="also at this policy's measured latency on this machine (in the --backend it runs on)")
    _add_backend_args(p)
    _field(p, "--episodes", EvalConfig, type=_positive_int, default=100)  # a sweep's settings: 100 test seeds
    _field(p, "--seed-start", EvalConfig, type=_nonneg_int)  # validation seeds (200000+) for choices
    _field(p, "--max-steps", EvalConfig, type=_positive_int)
    _add_task_flag(p, trained=True)
    _field(p, "--execution-horizon", EvalConfig, type=_positive_int, metavar="S")
    _add_strategy_args(p, sweep=True)
    p.add_argument("--out", metavar="DIR", help="output folder (its realtime-sweep.json is what a report reads: "
                   "put it inside a study's folder to add this sweep to the study's report)")
    p.add_argument("--label", help="the sweep's name in reports (default: the policy and its inference mode)")
    p.add_argument("--resume", action="store_true",
                   help="keep the settings an interrupted sweep already wrote to --out when they match this one "
                        "exactly (policy, checkpoint, episodes, seeds, strategy, horizon); measured ones are re-run")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    _add_wallclock_args(p)
    p.set_defaults(func="cmd_realtime")


def _add_wallclock_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("wall clock (docs/realtime.md, 'Wall-clock check')")
    g.add_argument("--wall-clock", action="store_true",
                   help="run the simulator in real time at 10 Hz against a policy server in another process (started "
                        "here on a free loopback port, or --server), async, every call's real delay recorded; then "
                        "the simulated-delay twin at the calls' median d, paired on the episode seeds")
    g.add_argument("--server", metavar="ADDR", help="a running `bcbench serve` (tcp://127.0.0.1:PORT) instead of one "
                   "started here; --checkpoint/--policy then name its policy for the simulated twin")
    g.add_argument("--allow-remote", action="store_true", help="allow a --server that is not on this machine")
    _field(g, "--plan-delay", WallClockConfig, type=_positive_int, metavar="D")
    g.add_argument("--server-threads", type=_positive_int, metavar="N",
                   help="torch threads of the server started here (default: the cores but one, which the "
                        "simulator keeps)")
    g.add_argument("--compare-with", metavar="EVAL_JSON", help="pair with this simulated record (async at the "
                   "rule's d, e.g. a sweep's realtime-async-dD.json) instead of running the twin here")
    g.add_argument("--no-compare", action="store_true", help="the wall-clock episodes only, no simulated twin")


def _add_serve_command(sub: Any) -> None:
    p = sub.add_parser("serve", help="a policy server (ZeroMQ, msgpack): predict/describe/ping requests answered by "
                       "one policy, as a robot's computer would run it (docs/realtime.md, 'Wall-clock check')")
    _add_policy_source_args(p)
    p.add_argument("--no-ema", action="store_true", help="use the raw weights even if the run kept an EMA")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="where the policy runs (default cpu)")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="the policy's own random seed (default 0)")
    _add_backend_args(p)
    p.add_argument("--bind", default="tcp://127.0.0.1:5555", metavar="ADDR",
                   help="where to listen (default tcp://127.0.0.1:5555; port * = any free one, printed); a "
                        "non-loopback address is refused unless --allow-remote")
    p.add_argument("--allow-remote", action="store_true", help="allow --bind on an address other machines reach")
    p.add_argument("--threads", type=_positive_int, help="torch threads (default torch's own choice)")
    p.set_defaults(func="cmd_serve")


def _add_deploy_commands(sub: Any) -> None:
    p = sub.add_parser("export", help="export a trained run's inference graphs for a deployment runtime")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a trained run")
    p.add_argument("--format", default="openvino", choices=["openvino"], help="runtime format (default openvino)")
    p.add_argument("--precision", default="fp32", choices=PRECISIONS,
                   help="fp32 (exact), bf16 (compiled with a bf16 hint), int8 (NNCF, calibrated on the "
                        "training split) or int8w (int8 weights only, no calibration); default fp32")
    p.add_argument("--no-ema", action="store_true", help="export the raw weights even if the run kept an EMA")
    p.set_defaults(func="cmd_export")

    p = sub.add_parser("publish", help="copy a trained run's inference weights (fp32, no trainer state) into a small "
                                       "model folder that eval/latency/realtime --checkpoint take on a fresh clone")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a trained run (its newest checkpoint is published)")
    p.add_argument("out", metavar="OUT", help="the model folder to write, e.g. models/diffusion-cpu")
    p.add_argument("--scores", required=True, metavar="EVAL_JSON",
                   help="the committed per-episode evaluation of exactly these weights (torch), which the published "
                        "model must reproduce; checked to be of this run, step and weights")
    p.add_argument("--force", action="store_true", help="replace OUT if it exists")
    p.set_defaults(func="cmd_publish")

    p = sub.add_parser("tiers", help="accuracy of each inference mode of a trained run against the exact torch one")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a trained run")
    p.add_argument("--mode", action="append", choices=[m for m in MODES if m != "fast"],
                   help="modes to compare with torch fast (default openvino fp32, bf16, int8 and int8w)")
    p.add_argument("--sampler", choices=["ddpm", "ddim", "euler", "midpoint"], help="generative policies' sampler")
    p.add_argument("--steps", type=_positive_int, help="generative policies' steps")
    p.add_argument("--episodes", type=_positive_int, default=100, help="test episodes per mode (default 100)")
    p.add_argument("--seed-start", type=int, default=100_000,
                   help="first episode seed (default 100000, the test seeds; 200000+ for validation: a run that "
                        "is not a final preset is compared there)")
    p.add_argument("--observations", type=_positive_int, default=100,
                   help="validation observations for the chunk deviation (default 100)")
    p.add_argument("--out", metavar="DIR", help="output folder (default RUN_DIR/tiers-SAMPLER)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func="cmd_tiers")


def _add_policy_arg(p: Any) -> None:
    p.add_argument("--policy-arg", action="append", metavar="KEY=VALUE",
                   help="keyword argument for an outside policy's factory (repeatable; JSON values, else strings)")


def _add_backend_args(p: Any) -> None:
    p.add_argument("--backend", "--mode", dest="backend", choices=[*BACKENDS, *MODES], metavar="BACKEND",
                   help="what runs a trained policy's networks: torch, openvino or onnxruntime (these two export "
                        "them, cached beside the checkpoint), auto (the fastest exact one here, measured), or a mode "
                        "by its `latency --backend` name (fast, openvino-bf16, ...; --mode is accepted too). Default: "
                        "auto where a measured latency sets the delays (--latency measured, --measured), else torch")
    p.add_argument("--precision", default="fp32", choices=PRECISIONS,
                   help="with --backend openvino: fp32 (exact, default), bf16, int8 or int8w (int8 weights only; "
                        "approximate); onnxruntime: fp32 or int8")
    p.add_argument("--reference", action="store_true",
                   help="torch's reference form (Diffusion Policy: the plain U-Net every step; same chunks)")


def _add_strategy_args(p: argparse.ArgumentParser, sweep: bool = False) -> None:
    """--strategy (several for a sweep: one sweep each, compared with naive) and each strategy's parameters."""
    if sweep:
        p.add_argument("--strategy", nargs="+", default=["naive"], choices=STRATEGIES, metavar="STRATEGY",
                       help=field_docs(StrategyConfig)["strategy"] + "; several: one sweep each, the report pairs "
                       "each with naive (default naive)")
    else:
        _field(p, "--strategy", StrategyConfig, choices=STRATEGIES)
    _field(p, "--rtc-max-guidance", StrategyConfig, type=_number(float, 0), metavar="BETA")
    _field(p, "--rtc-no-jacobian", StrategyConfig, name="rtc_jacobian", dest="rtc_jacobian", action="store_false")
    _field(p, "--bid-samples", StrategyConfig, type=_positive_int, metavar="N")
    _field(p, "--bid-modes", StrategyConfig, type=_positive_int, metavar="K")
    _field(p, "--bid-weak", StrategyConfig, metavar="RUN_DIR")
    _field(p, "--ensemble-decay", StrategyConfig, type=_number(float, 0), metavar="M")
    _field(p, "--correction", StrategyConfig, metavar="RUN_DIR")


def _add_eval_command(sub: Any) -> None:
    p = sub.add_parser("eval", help="evaluate a policy over seeded episodes of its task (JSON result, videos)")
    p.add_argument("--policy", metavar="NAME", help="policy to evaluate: a baseline (random, scripted), a plug-in, "
                   "or my_pkg.my_module:factory (`bcbench policies` lists them; a trained run: --checkpoint)")
    _add_policy_arg(p)
    p.add_argument("--preset", "--config", dest="preset", default="quick", choices=["quick", "cpu", "paper"],
                   help="a baseline's preset (default quick; --config is the old name of this option)")
    p.add_argument("--checkpoint", metavar="RUN_DIR", help="evaluate a trained run instead of --policy")
    p.add_argument("--no-ema", action="store_true", help="use the raw weights even if the run kept an EMA")
    _add_backend_args(p)
    p.add_argument("--sampler", choices=["ddpm", "ddim", "euler", "midpoint"],
                   help="generative policies: diffusion ddpm|ddim, flow euler|midpoint (default: the run's)")
    p.add_argument("--steps", type=_positive_int,
                   help="generative policies: denoising (diffusion, 1..100) or integration steps (default: the run's)")
    p.add_argument("--spacing", choices=["trailing", "leading"],
                   help="diffusion only: timestep spacing (default trailing: every step count starts from pure "
                        "noise; leading is diffusers' and the study's default)")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="where the policy runs (default cpu)")
    _field(p, "--episodes", EvalConfig, type=_positive_int)
    _field(p, "--seed-start", EvalConfig, type=_nonneg_int)
    p.add_argument("--seed", type=_nonneg_int, default=0, help="the policy's own random seed (default 0)")
    _field(p, "--max-steps", EvalConfig, type=_positive_int)
    _add_task_flag(p, trained=True)
    _field(p, "--action-horizon", EvalConfig, type=_positive_int)
    _field(p, "--workers", EvalConfig, type=_positive_int)
    _field(p, "--video", EvalConfig, type=_nonneg_int, metavar="N")
    _field(p, "--execution", EvalConfig, choices=EXECUTIONS)
    _field(p, "--latency-ms", EvalConfig, type=float, metavar="MS")
    _field(p, "--latency", EvalConfig, metavar="SOURCE")
    _field(p, "--execution-horizon", EvalConfig, type=_positive_int, metavar="S")
    _add_strategy_args(p)
    p.add_argument("--out", metavar="DIR", help="output folder (default runs/eval-POLICY-TIME)")
    p.add_argument("--record", metavar="FILE.npz", help="also write every step's observation and executed action "
                   "to this rollout store (what a correction head trains on: --set rollouts=FILE.npz)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func="cmd_eval")
