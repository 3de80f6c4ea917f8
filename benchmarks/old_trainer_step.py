"""Worker of `train_throughput.py --old-commit`: training steps as an older commit's trainer ran them.

    PYTHONPATH=OLD/src python benchmarks/old_trainer_step.py POLICY OVERRIDES_JSON BATCH THREADS

Runs with that commit's `src` first on the path (train_throughput.py extracts it with `git archive`), so the
model, its loss (crop included), the optimiser and the EMA are that commit's code. One step is the body of
its `Trainer.fit` loop on a CPU: the epoch permutation drawn anew, the batch gathered, forward in fp32,
backward, optimiser and schedule steps, the EMA update and the loss read back (logging). Reads a number of
steps per line on stdin and answers each line with one JSON list of step times in seconds; exits on EOF.
Its first line is {"ready": parameters}, or {"error": why} where the old commit cannot build this network.
It uses only names that the old and the new code both have, so it also runs against the current commit.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import torch


def main() -> None:
    name, overrides, batch, threads = sys.argv[1], json.loads(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    torch.set_num_threads(threads)
    from bcbench.data import load_replay_buffer, make_datasets, resolve_dataset
    from bcbench.policies import REGISTRY, make_config
    try:  # where the trainer kept them before the flat training loop, then where it keeps them now
        from bcbench.training.loop import EMA, make_optimizer, make_scheduler
    except ImportError:
        from bcbench.training.parts import EMA, make_optimizer, make_scheduler

    try:
        cfg = make_config(name, "quick", {**overrides, "optim.batch_size": batch})  # the network under test
    except Exception as exc:  # e.g. a policy or a config field that the old commit does not have
        print(json.dumps({"error": str(exc)}), flush=True)
        return
    ds = make_datasets(load_replay_buffer(resolve_dataset(None)))[0]
    torch.manual_seed(0)
    model = REGISTRY[name][1](cfg).train()
    o = cfg.optim
    opt = make_optimizer(model, o)
    sched = make_scheduler(opt, o, 10**6)
    ema = EMA(model, o.ema_power, o.ema_max_decay) if o.ema else None
    steps_per_epoch, step = len(ds) // batch, 0
    print(json.dumps({"ready": model.num_parameters()}), flush=True)
    for line in sys.stdin:
        times = []
        for _ in range(int(line)):
            t = time.perf_counter()
            epoch, i = divmod(step, steps_per_epoch)
            perm = np.random.default_rng([0, epoch]).permutation(len(ds))
            b = {k: torch.from_numpy(v) for k, v in ds.get_batch(perm[i * batch:(i + 1) * batch]).items()}
            loss = model.compute_loss(b)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if o.schedule != "plateau":
                sched.step()
            step += 1
            if ema is not None:
                ema.update(model, step)
            loss.item()
            times.append(time.perf_counter() - t)
        print(json.dumps(times), flush=True)


if __name__ == "__main__":
    main()
