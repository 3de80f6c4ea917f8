"""Where and when a report's numbers come from: the machines that evaluated and timed them, and the commits of
every result file, with a warning when they differ. Reads result rows only."""

from __future__ import annotations

from typing import Any

from bcbench.analysis.realtime import training_seed
from bcbench.analysis.results import Row, cpu_text
from bcbench.analysis.seeds import episodes_and_seeds
from bcbench.utils.system import CONTENDED_CPUS


def _threads(n: object) -> str:
    return f"{n} thread" + ("" if n == 1 else "s")


def _and(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _by_machine(rows: list[Row]) -> tuple[dict[tuple[str, str], dict[str, list[str]]], Any]:
    """(CPU, threads) -> label -> the training seeds (several) or settings of it run there, and `said(label,
    items)`, the words for one label's items ("seeds 1 and 2 of DP", "all 2 settings of Flow", "Flow euler1")."""
    multi = len({(r.label, r.train_seed) for r in rows}) > len({r.label for r in rows})
    by_hw: dict[tuple[str, str], dict[str, list[str]]] = {}  # (cpu, threads) -> label -> seeds or settings there
    settings: dict[str, set[str]] = {}  # label -> its settings, wherever they ran
    for r in rows:
        settings.setdefault(r.label, set()).add(r.variant)
        hw = (r.hardware.get("gpu") or cpu_text(r.hardware), _threads(r.hardware.get("torch_threads", "?")))
        item = (str(r.train_seed) if r.train_seed is not None else "") if multi else (
            "" if r.variant == "default" else r.variant)
        items = by_hw.setdefault(hw, {}).setdefault(r.label, [])
        if item not in items:
            items.append(item)

    def said(label: str, items: list[str]) -> list[str]:
        if multi:
            seeds = [i for i in items if i]
            return ([f"seed{'s' if len(seeds) > 1 else ''} {_and(seeds)} of {label}"] if seeds else []) + (
                [label] if "" in items else [])
        if len(items) > 1 and len(items) == len(settings[label]):
            return [f"all {len(items)} settings of {label}"]
        return [f"{label} {i}".rstrip() for i in items]

    return by_hw, said


def hardware_line(rows: list[Row]) -> str:
    """Where the rows were evaluated (and timed), said once: one machine, or each machine (CPU and torch threads)
    with what ran there. `rows` are one per run (not merged over training seeds: seeds of one setting may have run
    on different machines); with several training seeds a machine names the training seeds of each label it
    evaluated ("seeds 1 and 2 of label"), else the settings, a label whose settings all ran there once ("all N
    settings of label")."""
    by_hw, said = _by_machine(rows)
    timed = _timed_elsewhere(rows)
    did = "Evaluated and timed" if any(r.latency for r in rows) and not timed else "Evaluated"
    if len(by_hw) <= 1:
        return f"{did} on {', '.join(next(iter(by_hw), ('no machine',)))}.{timed}"
    cpus = sorted({cpu for cpu, _ in by_hw})
    parts = [f"{cpu}: " + "; ".join(", ".join(x for label, items in ran.items() for x in said(label, items))
                                    + f" with {t}" for (c, t), ran in sorted(by_hw.items()) if c == cpu)
             for cpu in cpus]
    return f"{did} on {'several machines: ' if len(cpus) > 1 else ''}" + "; ".join(parts) + "." + timed


MACHINES_HEADER = ["machine", "torch threads", "what it evaluated"]


def machine_rows(rows: list[Row]) -> list[list[str]]:
    """The compact table of a report evaluated on several machines (one row per CPU and thread count, with what
    ran there), which stands below the answer instead of a paragraph above it; empty for one machine."""
    by_hw, said = _by_machine(rows)
    if len(by_hw) <= 1:
        return []
    return [[cpu, t, ", ".join(x for label, items in ran.items() for x in said(label, items))]
            for (cpu, t), ran in sorted(by_hw.items())]


def _timed_elsewhere(rows: list[Row]) -> str:
    """' Timed on CPU, N threads.' when some row's latency was measured on another CPU (model or ISA flags) than the
    one that evaluated it, e.g. a study resumed on a new machine whose timing stages ran there; else ''. Two VMs
    can share a model name and family yet differ in flags (one exposes avx512_bf16), so flags count."""
    timed = [r for r in rows if r.latency and r.timed_hardware]
    if not any(cpu_text(r.timed_hardware) != cpu_text(r.hardware) for r in timed):
        return ""
    where = sorted({f"{cpu_text(r.timed_hardware)}, {_threads(r.timed_hardware.get('torch_threads', '?'))}"
                    for r in timed})
    return f" Timed on {'several machines: ' if len(where) > 1 else ''}{'; '.join(where)}."


def lead_line(name: str, rows: list[Row], mixed: bool, runs: list[Row] | None = None) -> str:
    """The report's first line: what it holds (`rows`: one per setting), on which episodes, where (`runs`: one row
    per run, which machine evaluated each); details follow at its end."""
    ns, seeds, k = episodes_and_seeds(rows)
    eps = (f"{'/'.join(map(str, ns))} episodes each (seeds {seeds[0]}-{seeds[-1]})" if seeds else "no episodes")
    if k:
        eps += f", {'/'.join(map(str, k))} training seeds per trained setting"
    machines = machine_rows(runs or rows)
    where = (f"Evaluated on {len(machines)} machines (the table 'Machines' under the answer)."
             + _timed_elsewhere(runs or rows) if machines else hardware_line(runs or rows))
    return (f"Study `{name}`: {len(rows)} evaluated settings, {eps}. {where}"
            + (" These results mix several commits: see Provenance at the end." if mixed else ""))


def _short(commit: str) -> str:
    """A commit as git abbreviates it for people (12 hex digits; a "-dirty" mark kept)."""
    base, dirty = (commit[:-6], "-dirty") if commit.endswith("-dirty") else (commit, "")
    return (base[:12] if len(base) == 40 else base) + dirty


def provenance_notes(rows: list[Row], commits_by_kind: dict[str, list[str]] | None = None,
                     reason: str = "") -> list[str]:
    """The commits every result file was produced at (each with the kinds of file it made), with a warning when
    several, and the study's recorded reason for it if it has one; a warning for a dirty tree."""
    by_kind = commits_by_kind or {c: [] for c in sorted({r.git_commit or "unknown" for r in rows})}
    commits = sorted(by_kind)
    named = [_short(c) + (f" ({', '.join(by_kind[c])})" if by_kind[c] and len(commits) > 1 else "") for c in commits]
    notes = [f"Produced at commit{'s' if len(commits) > 1 else ''}: " + ", ".join(named) + "."]
    if len(commits) > 1:
        notes.append("Warning: these results mix several commits; numbers from different code may not be comparable."
                     + (f" Why: {reason}" if reason else ""))
    if any(c.endswith("-dirty") for c in commits):
        notes.append("Warning: some results come from a working tree with uncommitted changes.")
    nodes: dict[str, list[str]] = {}
    for r in rows:
        if r.timed_on:
            nodes.setdefault(r.timed_on, []).append(f"{r.label} {r.variant}")
    if len(nodes) > 1:  # a cluster: latencies from different machines are not comparable as they stand
        notes.append("Timed on several machines: " + "; ".join(f"{n}: {', '.join(v)}" for n, v in sorted(nodes.items()))
                     + ".")
    elif nodes:
        notes.append(f"Timed on {next(iter(nodes))}.")
    quiet = timing_conditions(rows)
    if quiet:
        notes.append(quiet)
    return notes


def timing_conditions(rows: list[Row]) -> str:
    """Whether the machine was quiet while each row was timed, from the CPU use its timing recorded (other processes
    and the hypervisor's steal, in CPUs; bcbench.utils.system.CpuContention): a warning naming the rows timed beside
    other work, a statement when every recorded timing was quiet, nothing when no timing recorded it (older files)."""
    recorded, busy = 0, []
    for r in rows:
        for mode, stats in r.latency.items():
            c = stats.get("cpu_contention") if isinstance(stats, dict) else None
            if not c:
                continue
            recorded += 1
            if max(c["other_cpus"], c["steal_cpus"]) > CONTENDED_CPUS:
                busy.append(f"{r.label} {r.variant} {mode} ({c['other_cpus']:.2f} CPUs other, "
                            f"{c['steal_cpus']:.2f} stolen)")
    if busy:
        return (f"Warning: {len(busy)} of {recorded} timings were taken while other work used the CPUs (more than "
                f"{CONTENDED_CPUS} CPUs): " + "; ".join(busy) + ". Their times are not quiet-machine times.")
    if recorded:
        return (f"Every one of the {recorded} timings that recorded it ran on a quiet machine (other processes and "
                f"the hypervisor's steal under {CONTENDED_CPUS} CPUs each).")
    return ""


def paired_conditions(paired: dict[str, dict[str, Any]], shared: list[str] | None = None) -> list[str]:
    """The same for the interleaved timings (`latency-paired*.json`, by mode): one line per file that recorded what
    else ran (files from before it was recorded say nothing); and which labels share its medians
    (`findings.shared_timing`)."""
    out = [f"{' and '.join(shared)} take the same interleaved medians per setting: the interleaved timing times each "
           "setting once, on random weights, and their settings run the same calls (the same network, sampler and "
           "step count; the beta schedule changes constants only)."] if shared else []
    for timing in paired.values():
        c = timing.get("contention")
        if not c:
            continue
        busy = max(c["other_cpus"], c["steal_cpus"]) > CONTENDED_CPUS
        out.append(f"{'Warning: the' if busy else 'The'} interleaved timing {timing['file']} ran "
                   f"{'beside other work' if busy else 'on a quiet machine'} ({c['other_cpus']:.2f} CPUs other, "
                   f"{c['steal_cpus']:.2f} stolen, over {c['seconds']:.0f} s)"
                   + (": its times are not quiet-machine times." if busy else "."))
    return out


def sweep_provenance(realtime: dict[str, dict[str, Any]], rows: list[Row]) -> str:
    """What the real-time sweeps ran on, where the rows do not say it: the machines, when a sweep ran on a CPU that
    evaluated none of the rows (a study resumed on a new machine: a closed loop's episodes differ between CPUs in
    their last bits, so a sweep is read against its own sync, not the evaluation), and the training seed, where a
    sweep ran one model of a policy evaluated with several (its scores are that model's, not a mean over seeds)."""
    evaluated = {cpu_text(r.hardware) for r in rows if r.hardware}
    where: dict[str, dict[str, None]] = {}  # "CPU, N threads" -> the policies swept there (an ordered set)
    single: dict[tuple[int, int], dict[str, None]] = {}  # (its training seed, of how many) -> the policies swept so
    for label, settings in realtime.items():
        base = label.split(" + ")[0]  # a strategy's sweep of a policy ("BCT + ensemble"), a sampler's ("DP DDIM10")
        # the longest row label it starts with: "BeT (chunked)" before "BeT" when a study has both
        policy = max((r.label for r in rows if r.label == base or base.startswith(r.label + " ")), key=len,
                     default=base)
        hw = next((r["hardware"] for r in settings.values() if r.get("hardware")), {})
        if hw:
            where.setdefault(f"{cpu_text(hw)}, {_threads(hw.get('torch_threads', '?'))}", {})[policy] = None
        first = next(iter(settings.values()), {})
        if "training_seeds" in first.get("summary", {}):
            continue  # pooled over seeds: pooled_sentence names them
        seeds = {r.train_seed for r in rows if r.label == policy and r.train_seed is not None}
        if len(seeds) > 1:
            single.setdefault((training_seed(first), len(seeds)), {})[policy] = None
    out = []
    elsewhere = sorted((cpu, list(ps)) for cpu, ps in where.items() if cpu.rsplit(", ", 1)[0] not in evaluated)
    if elsewhere:
        out.append("Swept on " + "; ".join(f"{cpu} ({', '.join(policies)})" for cpu, policies in elsewhere)
                   + f", {'machines' if len(elsewhere) > 1 else 'a machine'} that evaluated none of the rows above "
                   f"({'; '.join(sorted(evaluated))}): a closed loop's episodes differ between CPUs in their last "
                   "bits, so each sweep is read against its own sync.")
    for (seed, n), policies in sorted(single.items()):
        out.append(f"Swept on training seed {seed} only (of the {n} evaluated): {', '.join(policies)}; those sweeps' "
                   "scores are that model's, not the mean over training seeds in the tables above.")
    return " ".join(out)
