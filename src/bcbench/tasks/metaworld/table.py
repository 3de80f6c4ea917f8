"""bcbench's MetaWorld tasks, as data (no MuJoCo import): difficulty group (Seo et al., 2022, as 3D Diffusion
Policy groups them), what the proprioception holds, and the episode cap. Filled in by measurement."""

from __future__ import annotations

TASKS: dict[str, dict] = {
    "drawer-open": {"difficulty": "easy"},
    "door-open": {"difficulty": "easy"},
    "peg-insert-side": {"difficulty": "medium"},
    "pick-place": {"difficulty": "hard"},
    "assembly": {"difficulty": "hard"},
    "stick-pull": {"difficulty": "very hard"},
}
