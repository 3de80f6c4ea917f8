"""The seed protocol (torch-free): which episode seeds a choice may read and which are kept for the final test.

- Test episodes: seeds 100000-100099, Diffusion Policy's and the literature's. Only a `confirm` study reads
  them, once per final preset; nothing is ever chosen because of a score on them. Where a test score did inform a
  decision all the same, the study says so in its own file (`test_informed`) and every report that reads it prints
  the decision under Provenance.
- Validation episodes: seeds 200000+. Learning curves and every `explore` study read these; every choice
  (recipe, preset, step count, which variant to run next) is made on them, over at least 50 episodes.
"""

from __future__ import annotations

import math

from bcbench.errors import BCBenchError

TEST_SEED_START = 100_000
TEST_EPISODES = 100
VALIDATION_SEED_START = 200_000
MIN_CHOICE_EPISODES = 50  # episodes behind any choice (a 20-episode curve point is too noisy: SE ~0.06)
PURPOSES = ("explore", "confirm")
STOPPED_BY_TIME = "stopped by time: schedule not finished"  # a training that hit its time limit (the report marks it)
DONE_TRAINING = ("finished", STOPPED_BY_TIME)  # how a training may end and count as done


def training_done(summary: dict) -> bool:
    """Whether a run's train_summary.json records a training that counts as done."""
    return summary.get("stopped") in DONE_TRAINING
# in a study folder: the runs a restore dropped, whose first model's files an export removes (bcbench.study.restore)
DROPPED_RUNS = "dropped-runs.jsonl"
# in a study folder: its own account of why its files come from several commits (the report prints it; a restore
# of a mixed export needs it)
MIXING_REASON = "mixing-reason.txt"


def held_out_episodes(n_episodes: int, val_fraction: float) -> int:
    """Demonstration episodes a run holds out for its validation loss: round(n x val_fraction), at least 1 when any
    (the study's 90/10 split; bcbench.data.split_episodes draws them, the analysis counts what a run trained on)."""
    return max(1, round(n_episodes * val_fraction)) if val_fraction > 0 else 0


def overlaps_test_seeds(seed_start: int, episodes: int) -> bool:
    """Whether episode seeds seed_start .. seed_start + episodes - 1 touch the test seeds."""
    return seed_start < TEST_SEED_START + TEST_EPISODES and seed_start + episodes > TEST_SEED_START


def check_purpose(purpose: str | None, seed_start: int, episodes: int) -> str | None:
    """None if the study's evaluation seeds fit its purpose, else the reason (one line)."""
    if purpose is None:
        return None  # written before the protocol: the report labels it
    if purpose not in PURPOSES:
        return f"purpose must be {' or '.join(PURPOSES)}, got {purpose!r}"
    if purpose == "explore":
        if overlaps_test_seeds(seed_start, episodes) or seed_start < VALIDATION_SEED_START:
            return (f"an explore study evaluates on validation seeds ({VALIDATION_SEED_START}+), not "
                    f"{seed_start}..{seed_start + episodes - 1}: the test seeds are kept for a confirm study")
        if episodes < MIN_CHOICE_EPISODES:
            return f"an explore study makes choices: it needs episodes >= {MIN_CHOICE_EPISODES}, got {episodes}"
    elif seed_start != TEST_SEED_START:
        return f"a confirm study evaluates on the test seeds from {TEST_SEED_START}, not from {seed_start}"
    return None

# Deviations from the protocol, named where they happened: each decision (a preset, a seed count, a stage added) that
# a TEST-seed result informed. A study file lists its own (study.test_informed), a combined report's combine.json
# lists every one of its studies' (and its own), and the report prints them under Provenance and "Which policy".
TEST_INFORMED_KEYS = ("decision", "read")  # what was decided; the result file (or report) whose test score informed it


def test_informed_entries(value: object, where: str, extra: tuple[str, ...] = ()) -> list[dict[str, str]]:
    """`value` checked as a list of {decision, read, *extra} tables of non-empty strings (one line if not)."""
    keys = (*TEST_INFORMED_KEYS, *extra)
    if not isinstance(value, list) or not all(
            isinstance(e, dict) and all(isinstance(e.get(k), str) and e[k].strip() for k in keys) for e in value):
        raise BCBenchError(f"{where} must list tables of {', '.join(keys)} (each a non-empty string)")
    return [dict(e) for e in value]


CONTROL_DT_S = 0.1  # Push-T's control period (10 Hz): a delay d is counted in these steps


SYNC_SETTING = "realtime-sync"  # a real-time sweep's d = 0 reference, shared by every execution mode


def delay_steps(latency_s: float, rate_hz: float | None = None) -> int:
    """Control steps a call of `latency_s` seconds takes: ceil(L / 0.1 s), or ceil(L f) at another rate `rate_hz`,
    with a hair of slack so that an exact multiple (0.2 s at 10 Hz) is not rounded up by floating point. The one
    rounding every delay in bcbench goes through (simulated, measured, wall-clock, `bcbench choose`)."""
    x = latency_s / CONTROL_DT_S if rate_hz is None else latency_s * rate_hz
    return max(0, math.ceil(x - 1e-9))


def delay_setting(execution: str, d: int) -> str:
    """A real-time sweep's setting at fixed delay d as its records name it: realtime-EXECUTION-dD, and the sync
    reference for d = 0 (no delay leaves nothing for the execution mode to do)."""
    return SYNC_SETTING if d == 0 else f"realtime-{execution}-d{d}"


def strategy_label(policy: str, strategy: str) -> str:
    """A real-time sweep's label: the policy's own for naive, "POLICY + STRATEGY" for any other execution strategy
    (so a report can set each strategy beside the same policy's naive sweep; `policy_label` reads it back)."""
    return policy if strategy == "naive" else f"{policy} + {strategy}"


def policy_label(label: str, strategy: str) -> str:
    """The policy's label of a sweep labelled by `strategy_label` with `strategy`."""
    return label if strategy == "naive" else label.replace(f" + {strategy}", "", 1)
