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


@pytest.mark.parametrize(("name", "epoch"), EPOCHS)
def test_a_confirm_spec_holds_the_generated_runs(name, epoch):
    from bcbench.study.spec import load_spec

    path = ROOT / "studies" / f"metaworld-confirm-{name}.toml"
    assert path.read_text().rstrip().endswith(_blocks()(epoch, "4/3").rstrip())
    runs = load_spec(str(path)).runs
    assert len(runs) == 15 and sum(r.doubles is not None for r in runs) == 2
    assert all(r.overrides.get("pred_horizon") == 4 for r in runs if r.policy != "random")


def test_the_default_horizons_add_no_override():
    assert "pred_horizon" not in _blocks()(229, "16/8")
