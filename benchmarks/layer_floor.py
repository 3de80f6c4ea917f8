"""The per-layer roofline beside a committed latency table's floor: how far each exact mode is from what
layer-by-layer execution allows on the machine that table measured.

    .venv/bin/python benchmarks/layer_floor.py results/latency-floor-xeon/glue-one-thread/latency.json

A latency record's floor (bcbench.evaluation.floor.floor_ms) is max(bytes / bandwidth, FLOPs / throughput) over
the whole call: it assumes the weight reads of memory-bound layers overlap the arithmetic of compute-bound ones.
A runtime that runs one layer after another cannot do that, so this script also states the per-layer roofline,
the sum over modules of max(bytes / bandwidth, FLOPs / throughput) (`layer_work`, `layer_floor_ms`), with the
table's own best limits, and each row's median against both. It counts (one untimed call first, as the table
counted after its timed calls); it times nothing, so it may run beside other work. Writes layer-floor.json beside
the table (each policy's ten costliest modules too), stamped with commit and CPU.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from bcbench.evaluation.backends import apply_mode
from bcbench.evaluation.benchmark import _normalizer
from bcbench.evaluation.floor import floor_ms, layer_floor_ms, layer_work, work_totals
from bcbench.interface import example_observation
from bcbench.policies import make_policy
from bcbench.policies.learned import PolicyRunner
from bcbench.utils.io import read_json, write_json
from bcbench.utils.system import provenance

EXACT = ("fast", "openvino-fp32", "onnxruntime-fp32", "auto")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("latency_json")
    args = ap.parse_args()
    table = read_json(args.latency_json)
    limits = table["machine_limits"]
    torch.set_num_threads(int(limits.get("threads", 2)))
    out = []
    for policy, variant in dict.fromkeys((r["policy"], r["variant"]) for r in table["rows"]):
        rows = [r for r in table["rows"] if (r["policy"], r["variant"]) == (policy, variant) and r["mode"] in EXACT]
        if not rows or not rows[0].get("weight_bytes"):
            continue
        torch.manual_seed(0)
        model = make_policy(policy, rows[0]["preset"]).eval()
        runner = PolicyRunner(model, _normalizer())
        apply_mode(runner, "fast")  # the torch form the exact runtimes export (FiLM hoisted)
        if model.samplers:
            model.set_sampler(variant.rstrip("0123456789"), int(variant[len(variant.rstrip("0123456789")):]))
        runner.predict_action_chunk(example_observation(1, runner.obs_horizon))  # steady state, as the table counted
        layers = layer_work(runner)
        whole = floor_ms(work_totals(layers), limits)
        per_layer = layer_floor_ms(layers, limits)
        costliest = sorted(layers, key=lambda x: -layer_floor_ms([x], limits))[:10]
        entry = {"policy": policy, "variant": variant, "floor_ms": whole["floor_ms"], "bound": whole["bound"],
                 "layer_floor_ms": per_layer, "modules": len(layers),
                 "modes": {r["mode"]: {"median_ms": r["median_ms"], "x_floor": r["median_ms"] / whole["floor_ms"],
                                       "x_layer_floor": r["median_ms"] / per_layer} for r in rows},
                 "costliest": [{**x, "floor_ms": layer_floor_ms([x], limits)} for x in costliest]}
        out.append(entry)
        best = min(entry["modes"].items(), key=lambda kv: kv[1]["median_ms"])
        print(f"{policy} {variant}: floor {whole['floor_ms']:.2f} ms ({whole['bound']}), per-layer floor "
              f"{per_layer:.2f} ms; fastest exact {best[0]} {best[1]['median_ms']:.2f} ms = x{best[1]['x_floor']:.2f} "
              f"floor, x{best[1]['x_layer_floor']:.2f} per-layer floor", flush=True)
    write_json(Path(args.latency_json).with_name("layer-floor.json"),
               {"source": str(args.latency_json), "source_commit": table.get("git_commit"), "limits": limits,
                "rule": layer_floor_ms.__doc__, "policies": out, **provenance()})


if __name__ == "__main__":
    main()
