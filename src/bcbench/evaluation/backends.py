"""Where a policy's inference graphs run: torch (reference or fast form), OpenVINO (fp32, bf16, int8, int8w) or ONNX
Runtime (bcbench.evaluation.onnx_runtime).

A policy's `predict_action_chunk` calls its networks through `call_graph` (bcbench.policies.learned); a
mode only flips the policy's switches, so every mode runs the same Python around the same graphs:

    reference      torch fp32; Diffusion Policy and flow call the plain U-Net at every step (the paper's way)
    fast           torch fp32; FiLM split (bcbench.policies.denoiser): exact, the default of eval and study
    openvino-fp32  the graphs exported to OpenVINO and compiled for this CPU at f32: exact
    openvino-bf16  the same with a bf16 inference-precision hint: approximate (weights and math in bf16)
    openvino-int8  NNCF post-training quantisation (calibrated on training-split observations), the ops it
                   leaves in float at bf16 where the CPU computes bf16 natively: approximate
    openvino-int8w NNCF weight compression: the matrix products' weights stored in int8 (per output channel,
                   asymmetric) and widened on the fly, activations in float (bf16 where native); approximate

Why int8w beside int8: a static int8 graph has one scale per activation tensor, fixed at calibration, while a
denoiser's activations change range over the sampling steps (noise in, clean chunk out). On the flow recipe-B
model (results/tiers-flow-b-explore/int8-cause/) static int8 moved chunks by 16 px on average (the U-Net
alone: 7 px; with only its matrix products quantised: 5.5 px), weight-only int8 by 0.9 px, as bf16 does. At
batch 1 a U-Net step is bound by reading its weights, so int8 weights keep most of int8's speed.

Exports of a trained run are cached under RUN_DIR/export/ (openvino-float-KEY serves fp32 and bf16, which
differ only in the compile hint; openvino-int8-KEY; openvino-int8w-KEY), keyed by the checkpoint, the weights
(EMA or raw), the precision and the OpenVINO version, and rebuilt when any of them changes; files are written
atomically.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import tempfile
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bcbench.data.sequence import make_datasets
from bcbench.errors import BCBenchError
from bcbench.evaluation.auto import choose_mode
from bcbench.evaluation.onnx_runtime import deploy_onnxruntime, ort_version, reduce_range
from bcbench.interface import FilmSplittable
from bcbench.modes import AUTO, MODES, TORCH_MODES
from bcbench.policies.checkpoint import read_run, weights_file
from bcbench.policies.learned import BCPolicy, GraphModule, PolicyRunner

GRAPH_FORMAT = 2  # bump when a policy's graphs change meaning: cached exports are then rebuilt


def _openvino() -> Any:
    try:
        import openvino  # optional at run time: the torch modes work without it
    except Exception as e:
        raise BCBenchError(f"the OpenVINO backend needs the openvino package (make install): {e}") from e
    return openvino


class _Compiled:
    """A compiled OpenVINO graph called like the torch method: torch tensors in, torch tensors out.

    Compiled for any batch (evaluation runs many episodes at once); a graph of the denoising loop also, on
    first use, for batch 1 with static shapes (a robot's call; measured 18.6 vs 24.0 ms for the paper U-Net
    step in f32). Not every graph: openvino 2026.4 crashes compiling the static-shape encoder graph with an
    f32 precision hint, and a graph called once per call gains little.
    """

    def __init__(self, core: Any, xml: Path, config: dict[str, Any], static_batch1: bool) -> None:
        self.core, self.config, self.static_batch1 = core, config, static_batch1
        # keep the graph in memory (not its path): an export to a temporary folder is deleted once compiled
        self.model = model = core.read_model(str(xml))
        self.requests = {None: core.compile_model(model, "CPU", config).create_infer_request()}
        self.n_out = len(model.outputs)

    def _request(self, batch: int) -> Any:
        if batch != 1 or not self.static_batch1:
            return self.requests[None]
        if 1 not in self.requests:
            static = self.model.clone()
            static.reshape({inp.get_any_name(): [1, *(d.get_length() for d in list(inp.get_partial_shape())[1:])]
                            for inp in static.inputs})
            self.requests[1] = self.core.compile_model(static, "CPU", self.config).create_infer_request()
        return self.requests[1]

    def __call__(self, *args: torch.Tensor) -> Any:
        request = self._request(args[0].shape[0])
        request.infer([np.ascontiguousarray(a.detach().cpu().numpy()) for a in args])
        # copy: the request reuses its output buffers on the next call
        outs = [torch.from_numpy(request.get_output_tensor(i).data.copy()) for i in range(self.n_out)]
        return outs[0] if self.n_out == 1 else tuple(outs)


def record_graph_inputs(model: BCPolicy, observations: Iterable[dict[str, torch.Tensor]]) -> dict[str, list[tuple]]:
    """Run the torch policy on `observations`, keeping every graph call's inputs (int8 calibration data)."""
    calls: dict[str, list[tuple]] = {name: [] for name in model.graphs}

    def recorder(name: str) -> Callable[..., Any]:
        def call(*args: torch.Tensor) -> Any:
            calls[name].append(tuple(a.detach().cpu().numpy() for a in args))
            return getattr(model, name)(*args)
        return call

    model.deployed = {name: recorder(name) for name in model.graphs}
    try:
        with torch.inference_mode():
            for obs in observations:
                model.predict_action_chunk(obs)
    finally:
        model.deployed = None
    return calls


def export_openvino(model: BCPolicy, precision: str, out_dir: Path,
                    calibration: list[dict[str, torch.Tensor]] | None = None) -> Path:
    """Write the policy's graphs as OpenVINO IR (`NAME.xml` + `.bin` each) into `out_dir`, atomically."""
    ov = _openvino()
    if precision == "int8" and not calibration:
        raise BCBenchError("int8 export needs calibration observations")
    model = model.eval()
    recorded = record_graph_inputs(model, calibration) if precision == "int8" else {}
    tmp = out_dir.with_name(out_dir.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name, example in model.graph_inputs(1).items():
        shapes = [ov.PartialShape([-1, *a.shape[1:]]) for a in example]  # any batch, fixed the rest
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # tracer notes on shape checks that are constant for a policy
            ov_model = ov.convert_model(GraphModule(model, name).eval(), example_input=example, input=shapes)
        if precision == "int8":
            import nncf  # heavy (seconds to import): only for int8

            data = recorded[name][:300]
            kind = nncf.ModelType.TRANSFORMER if model.name in ("bet", "bct") else None
            ov_model = nncf.quantize(ov_model, nncf.Dataset(data), subset_size=len(data), model_type=kind)
        elif precision == "int8w" and name in (model.loop_graphs or model.graphs):
            # the denoising loop's graphs only, where a policy has one: the encoder runs once per call, gains
            # little, and costs accuracy (flow recipe B: 1.3 px mean chunk deviation compressed, 0.9 px not)
            import nncf

            ov_model = nncf.compress_weights(ov_model, mode=nncf.CompressWeightsMode.INT8_ASYM)
        ov.save_model(ov_model, str(tmp / f"{name}.xml"), compress_to_fp16=False)
    shutil.rmtree(out_dir, ignore_errors=True)
    tmp.rename(out_dir)
    return out_dir


def export_key(model: BCPolicy, precision: str, checkpoint: Path | None, weights: str,
               runtime: str | None = None) -> str:
    """What an export depends on: the checkpoint file, the weights used, the precision, the runtime's version
    (OpenVINO's unless `runtime` names another)."""
    stat = ""
    if checkpoint is not None:
        f = weights_file(checkpoint, weights)
        st = f.stat()
        stat = f"{f}:{st.st_size}:{st.st_mtime_ns}"
    graphs = precision if precision.startswith("int8") else "float"  # fp32 and bf16 compile the same graphs
    blob = json.dumps([model.name, stat, weights, graphs, runtime or _openvino().__version__, GRAPH_FORMAT])
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def deploy_openvino(model: BCPolicy, precision: str, export_dir: Path | None = None,
                    calibration: list[dict[str, torch.Tensor]] | None = None, threads: int | None = None) -> None:
    """Compile the policy's graphs with OpenVINO and plug them in (`model.deployed`); exports cached in export_dir."""
    if export_dir is None:  # nothing to cache it in (an untrained policy): export, compile, delete
        with tempfile.TemporaryDirectory(prefix="bcbench-ov-") as tmp:
            deploy_openvino(model, precision, Path(tmp) / "graphs", calibration, threads)
        model.deployment["export"] = None
        return
    ov = _openvino()
    if not all((export_dir / f"{n}.xml").exists() for n in model.graphs):
        export_openvino(model, precision, export_dir, calibration)
    core = ov.Core()
    bf16 = "bf16" in " ".join(core.get_property("CPU", "OPTIMIZATION_CAPABILITIES")).lower()
    hint = "bf16" if precision == "bf16" or (precision.startswith("int8") and bf16) else "f32"
    config = {"PERFORMANCE_HINT": "LATENCY", "NUM_STREAMS": 1, "INFERENCE_PRECISION_HINT": hint,
              "INFERENCE_NUM_THREADS": threads or torch.get_num_threads()}
    model.deployed = {name: _Compiled(core, export_dir / f"{name}.xml", config, name in model.loop_graphs)
                      for name in model.graphs}
    model.deployment = {"backend": "openvino", "precision": precision, "inference_precision": hint,
                        "openvino": ov.__version__, "export": str(export_dir)}


def set_mode(model: BCPolicy, mode: str, export_dir: Path | None = None,
             calibration: list[dict[str, torch.Tensor]] | None = None) -> None:
    """Put a policy in one of MODES (flips its switches; OpenVINO modes compile its graphs)."""
    if mode not in MODES:
        raise BCBenchError(f"unknown inference mode '{mode}' ({', '.join(MODES)})")
    if isinstance(model, FilmSplittable):
        model.split_film = mode != "reference"
    model.deployed, model.deployment = None, {"backend": "torch", "precision": "fp32"}
    if mode.startswith("openvino-"):
        deploy_openvino(model, mode.removeprefix("openvino-"), export_dir, calibration)
    elif mode.startswith("onnxruntime-"):  # its own folder beside OpenVINO's (each export replaces its whole folder)
        deploy_onnxruntime(model, export_dir and export_dir.with_name(export_dir.name + "-onnxruntime"),
                           precision=mode.removeprefix("onnxruntime-"))


def dataset_observations(model: BCPolicy, split: str, n: int, seed: int = 0,
                         data_split: dict[str, Any] | None = None) -> list[dict[str, torch.Tensor]]:
    """`n` single observation windows (normalised, batch 1) of the training or validation split; `data_split`
    is a run's (run.json: val_fraction, split_seed, demos), so its training episodes are the ones it trained on."""
    c = model.config
    d = data_split or {}
    train, val, _ = make_datasets(model.task.demonstrations(), d.get("val_fraction", 0.1), d.get("split_seed", 0),
                                  c.obs_horizon, c.pred_horizon, c.action_horizon, model.state_dim, d.get("demos"))
    ds = train if split == "train" else val
    ids = np.random.default_rng(seed).choice(len(ds), size=min(n, len(ds)), replace=False)
    batches = (ds.get_batch(np.array([i])) for i in ids)
    return [{"image": torch.from_numpy(b["image"]), "agent_pos": torch.from_numpy(b["agent_pos"])} for b in batches]


def run_data_split(run_dir: str | Path) -> dict[str, Any]:
    return read_run(Path(run_dir)).get("data_split", {})


def _export_dir(runner: PolicyRunner, mode: str) -> Path | None:
    """Where a trained run caches `mode`'s export: RUN_DIR/export/{openvino|onnx}-{float|int8|int8w}-KEY, keyed by the
    checkpoint, weights, precision and runtime version (None: a torch mode, or an untrained policy)."""
    info = runner.info
    backend, _, precision = mode.partition("-")
    if backend not in ("openvino", "onnxruntime") or not (info.run_dir and info.checkpoint):
        return None
    runtime = None  # OpenVINO's version
    if backend == "onnxruntime":  # int8 built for a CPU without VNNI (7-bit weights) is another export
        runtime = f"onnxruntime-{ort_version()}" + ("-7bit" if precision == "int8" and reduce_range() else "")
    key = export_key(runner.model, precision, Path(info.run_dir) / "checkpoints" / info.checkpoint,
                     info.weights or "ema", runtime)
    prefix = "onnx" if backend == "onnxruntime" else "openvino"  # set_mode appends -onnxruntime to the former
    return Path(info.run_dir) / "export" / f"{prefix}-{precision if precision.startswith('int8') else 'float'}-{key}"


def apply_mode(runner: PolicyRunner, mode: str, torch_only: str = "") -> None:
    """Put a PolicyRunner's policy in `mode`; a trained run's exports are cached under RUN_DIR/export/. `auto`:
    the fastest exact mode for this checkpoint on this machine (bcbench.evaluation.auto), recorded as chosen;
    `torch_only` (why, e.g. a strategy that needs autograd) restricts it to torch's fast form, as does a GPU: the
    exported runtimes run on the CPU here, so on a GPU `auto` is torch and naming one of them is an error."""
    on_gpu = runner.device.type != "cpu"
    if on_gpu and mode not in TORCH_MODES:
        raise BCBenchError(f"mode {mode} runs on the CPU (bcbench exports for OpenVINO's and ONNX Runtime's CPU "
                           f"plugins); with --device {runner.device.type} use --backend torch or auto")
    if mode == AUTO:
        if on_gpu:  # nothing to choose between, so nothing to time
            trial = {"chosen": "fast", "cached": False, "why": f"the policy runs on {runner.device.type}: only torch "
                     "runs it there (the exports are CPU ones)"}
        else:
            torch_only = torch_only if runner.model.guidance_autograd else ""  # only flow's VJP
            trial = (choose_mode(runner, apply_mode, ("fast",), torch_only) if torch_only
                     else choose_mode(runner, apply_mode))
        apply_mode(runner, trial["chosen"])
        runner.info.deployment = {**(runner.info.deployment or {}), "auto": trial}
        return
    model, run_dir = runner.model, runner.info.run_dir
    export_dir, calibration = _export_dir(runner, mode), None
    if mode == "openvino-int8" and not (export_dir and export_dir.exists()):
        # calibration on training-split observations; an untrained model (timing only) gets random ones
        calibration = (dataset_observations(model, "train", 64, data_split=run_data_split(run_dir)) if run_dir
                       else [model.example_obs() for _ in range(8)])
    set_mode(model, mode, export_dir, calibration)
    runner.info.mode, runner.info.deployment = mode, model.deployment
