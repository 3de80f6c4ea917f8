"""Migration (issues 29 and 30): give committed run.json files written before runs recorded their preset a
`preset_values` entry (the preset's value of each override) and, for `cpu` presets, `preset_deviations` (how the
preset departs from the paper's recipe), so that the report (which reads files only) describes each run by its
own preset even after a preset is re-chosen.

For each run.json under the given results folders missing either entry, the preset is rebuilt at this commit and
checked to be the one the run was made with: its config with the overrides applied must equal the run's recorded
config. Only then are the entries written (atomically); a mismatch is reported and left alone. Run it before a
preset changes.   Usage: python scripts/backfill_preset_values.py results/*/
"""

from __future__ import annotations

import sys
from pathlib import Path

from bcbench.policies import make_config
from bcbench.policies.config import config_to_dict, dotted_value
from bcbench.reference import CPU_DEVIATIONS
from bcbench.utils.io import read_json, write_json


def backfill(run_json: Path) -> str:
    meta = read_json(run_json)
    overrides = meta.get("overrides") or {}
    need_values = bool(overrides) and "preset_values" not in meta
    need_dev = (meta.get("preset") or "").startswith("cpu") and meta["policy"] in CPU_DEVIATIONS \
        and "preset_deviations" not in meta
    if not (need_values or need_dev):
        return "skip"
    rebuilt = config_to_dict(make_config(meta["policy"], meta["preset"], overrides))
    if read_json_like(rebuilt) != meta["config"]:
        return "MISMATCH: the preset changed since this run; left alone"
    if need_values:
        preset = config_to_dict(make_config(meta["policy"], meta["preset"]))
        meta["preset_values"] = {k: dotted_value(preset, k) for k in overrides}
    if need_dev:
        meta["preset_deviations"] = CPU_DEVIATIONS[meta["policy"]]
    write_json(run_json, meta)
    return "filled"


def read_json_like(d: object) -> object:
    """Tuples as lists, as the JSON file holds them."""
    if isinstance(d, dict):
        return {k: read_json_like(v) for k, v in d.items()}
    if isinstance(d, list | tuple):
        return [read_json_like(v) for v in d]
    return d


if __name__ == "__main__":
    for folder in sys.argv[1:]:
        for f in sorted(Path(folder).glob("runs/*/run.json")):
            print(f, backfill(f))
