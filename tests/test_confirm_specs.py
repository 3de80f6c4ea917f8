"""The MetaWorld confirm specs' runs are what scripts/metaworld_confirm_runs.py writes for their task's epoch."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]


def _blocks():
    path = ROOT / "scripts" / "metaworld_confirm_runs.py"
    spec = importlib.util.spec_from_file_location("metaworld_confirm_runs", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.blocks


# an epoch of 200 demonstrations per task (scripts/metaworld_confirm_runs.py says how it is counted)
EPOCHS = [("peg", 291), ("drawer", 229), ("door", 211), ("pick", 129), ("assembly", 233)]
CHECKED = {"pick": ("bct",), "assembly": ("bct",)}  # a twice-the-steps check beyond DP's and flow's (its spec says why)


@pytest.mark.parametrize(("name", "epoch"), EPOCHS)
def test_a_confirm_spec_holds_the_generated_runs(name, epoch):
    from bcbench.study.spec import load_spec

    path = ROOT / "studies" / f"metaworld-confirm-{name}.toml"
    checked = CHECKED.get(name, ())
    assert path.read_text().rstrip().endswith(_blocks()(epoch, "4/3", checked).rstrip())
    spec = load_spec(str(path))
    runs = spec.runs
    assert len(runs) == 15 + len(checked) and sum(r.doubles is not None for r in runs) == 2 + len(checked)
    assert all(r.overrides.get("pred_horizon") == 4 for r in runs if r.policy != "random")
    # a check added because of a test score is listed as the protocol's exception
    assert bool(checked) == bool(spec.test_informed)


def test_an_added_check_runs_after_seed_1_and_doubles_seed_0():
    runs = _blocks()(129, "4/3", ("bct",)).split("\n\n[[run]]")
    labels = [next(x for x in r.splitlines() if x.startswith("label")) for r in runs]
    at = labels.index('label = "BCT, 10 demos, horizons 4 / 3, twice the steps"')
    assert "seeds = [1]" in runs[at - 1] and "BCT" in labels[at - 1] and "seeds = [2]" in runs[at + 1]
    assert "steps = 7740" in runs[at] and 'doubles = "BCT, 10 demos, horizons 4 / 3"' in runs[at]


def test_the_default_horizons_add_no_override():
    assert "pred_horizon" not in _blocks()(229, "16/8")


BAD_CHECKS = [["129", "4/3", "--check"], ["129", "--check=bct"], ["129", "--check", "bct", "--check", "bct"],
              ["129", "--check", "flow"]]  # nothing named, another spelling, twice, one always checked


@pytest.mark.parametrize("args", BAD_CHECKS)
def test_a_bad_check_is_the_usage_line(args):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "metaworld_confirm_runs.py"), *args],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stdout == "" and proc.stderr.startswith("usage:"), proc
