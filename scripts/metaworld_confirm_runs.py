"""Print the [[run]] blocks of a MetaWorld confirm study (issue 75), in the order the studies run them.

    python scripts/metaworld_confirm_runs.py EPOCH [HORIZONS] [--check POLICY]   e.g. 291 4/3 (peg-insert-side)

EPOCH: the task's steps in an epoch of 200 demonstrations (its explore stages' `optim.val_every`): the windows of the
store's 180 training episodes at horizons 16 / 8, over batch 64, rounded down (door-open 211, pick-place 129, assembly
233). The budgets are the explore stages': DP and flow 8,000 x 64, BCT and BeT 30 epochs, ResNet-50 CNN and CNN-MLP
20; 10 demonstrations. Order, most informative first: seed 0 of every learned policy, random, seeds 1 and 2 of DP,
flow and BCT, then DP's and flow's twice-the-steps checks. --check POLICY adds one for another policy's seed 0, after
seed 1 (pick-place's BCT: its best setting, which the why-not reads; added while its study ran, so a test score
informed it: the spec lists it). studies/metaworld-confirm-{peg,drawer,door,pick,assembly}.toml hold its output under
their header."""

from __future__ import annotations

import sys

LABELS = {"diffusion": "Diffusion Policy (cosine)", "flow": "Flow matching (DP's network)", "bct": "BCT", "bet": "BeT",
          "resnet50": "ResNet-50 CNN", "cnn_mlp": "CNN-MLP"}
EVALS = {"diffusion": '[{ sampler = "ddim", steps = [10] }, { sampler = "ddpm", steps = [10, 100] }]',
         "flow": '[{ sampler = "euler", steps = [2, 10] }]'}


def blocks(epoch: int, horizons: str = "4/3", checked: tuple[str, ...] = ()) -> str:
    pred, act = map(int, horizons.split("/"))
    extra = f", pred_horizon = {pred}, action_horizon = {act}" if (pred, act) != (16, 8) else ""
    tail = f"10 demos, horizons {pred} / {act}"
    steps = {"diffusion": 8000, "flow": 8000, "bct": 30 * epoch, "bet": 30 * epoch, "resnet50": 20 * epoch,
             "cnn_mlp": 20 * epoch}

    def run(policy: str, seed: int, doubled: bool = False) -> str:
        n = steps[policy] * (2 if doubled else 1)
        lines = ["", "[[run]]", f'policy = "{policy}"', 'preset = "cpu"',
                 f'label = "{LABELS[policy]}, {tail}' + (', twice the steps"' if doubled else '"'), "demos = 10",
                 f"seeds = [{seed}]", f"steps = {n}"]
        if policy in EVALS:
            lines.append(f"eval_every = {n // 2}")
        lines.append(f'set = {{ "optim.precision" = "fp32", "optim.val_every" = {epoch}{extra} }}')
        if policy in EVALS:
            lines.append(f"eval = {EVALS[policy]}")
        if doubled:
            lines.append(f'doubles = "{LABELS[policy]}, {tail}"')
        return "\n".join(lines)

    out = [run(p, 0) for p in ("diffusion", "flow", "bct", "resnet50", "bet", "cnn_mlp")]
    out.append('\n[[run]]\npolicy = "random"\nlabel = "random"')
    out += [run(p, 1) for p in ("diffusion", "flow", "bct")]
    out += [run(p, 0, doubled=True) for p in checked]
    out += [run(p, 2) for p in ("diffusion", "flow", "bct")]
    out += [run(p, 0, doubled=True) for p in ("diffusion", "flow")]
    return "\n".join(out)


if __name__ == "__main__":
    args, checked, bad = sys.argv[1:], [], False
    while "--check" in args:
        i = args.index("--check")
        bad = bad or i + 1 == len(args)  # a trailing --check names nothing
        checked += args[i + 1:i + 2]
        args = args[:i] + args[i + 2:]
    others = ("bct", "bet", "resnet50", "cnn_mlp")  # DP's and flow's checks are always there
    bad = bad or not all(c in others for c in checked) or len(set(checked)) < len(checked)
    bad = bad or any(a.startswith("-") for a in args)  # --check=bct and other spellings
    if len(args) not in (1, 2) or not args[0].isdigit() or bad:
        print("usage: python scripts/metaworld_confirm_runs.py EPOCH [PRED/ACT] [--check bct|bet|resnet50|cnn_mlp]",
              file=sys.stderr)
        sys.exit(2)
    print(blocks(int(args[0]), *args[1:], checked=tuple(checked)))
