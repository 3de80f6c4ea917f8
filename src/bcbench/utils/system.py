"""What a result was measured on: hardware, threads, library versions, git commit."""

from __future__ import annotations

import functools
import os
import platform
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import Any

from bcbench.errors import BCBenchError

_PACKAGES = ("bcbench", "torch", "numpy", "gymnasium", "gym-pusht", "pymunk", "shapely", "zarr", "diffusers")


def _cpuinfo_first(text: str) -> dict[str, str]:
    """The fields of the first processor in /proc/cpuinfo's text (every core of these machines is the same)."""
    out: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            if out:
                break
            continue
        key, _, value = line.partition(":")
        out.setdefault(key.strip(), value.strip())
    return out


@functools.cache
def _cpuinfo() -> dict[str, str]:
    try:
        return _cpuinfo_first(Path("/proc/cpuinfo").read_text())
    except OSError:
        return {}


def cpu_model() -> str:
    return _cpuinfo().get("model name") or platform.processor() or platform.machine()


def cpu_id_of(fields: dict[str, str]) -> str | None:
    """'GenuineIntel family 6 model 207 stepping 2' from cpuinfo fields; None where they are missing (ARM).
    Why: under KVM the model name is generic ("AMD EPYC", "Intel(R) Xeon(R) Processor") and one name has covered
    CPUs as different as a Zen 3 and a Zen 5; family and model tell them apart in a record."""
    keys = ("vendor_id", "cpu family", "model", "stepping")
    if not all(fields.get(k) for k in keys):
        return None
    vendor, family, model, stepping = (fields[k] for k in keys)
    return f"{vendor} family {family} model {model} stepping {stepping}"


def cpu_id() -> str | None:
    """This CPU's vendor, family, model and stepping (`cpu_id_of`)."""
    return cpu_id_of(_cpuinfo())


# The instruction-set features that decide which kernels (and precisions) run fast on a CPU.
ISA_FLAGS = ("avx2", "fma", "avx_vnni", "avx512f", "avx512_vnni", "avx512_bf16", "amx_tile", "amx_bf16", "amx_int8",
             "asimd", "sve")


@functools.cache
def cpu_flags() -> tuple[str, ...]:
    """This CPU's ISA_FLAGS that are present (from /proc/cpuinfo: x86's flags, ARM's Features; empty where it
    cannot be read)."""
    info = _cpuinfo()
    have = set((info.get("flags") or info.get("Features") or "").split())
    return tuple(f for f in ISA_FLAGS if f in have)


def cpu_record() -> dict[str, Any]:
    """The CPU as every timing and training record names it: model name, vendor/family/model/stepping, ISA flags."""
    return {"cpu_model": cpu_model(), "cpu_id": cpu_id(), "cpu_flags": list(cpu_flags())}


def cpu_has_vnni() -> bool:
    """Whether this CPU has an int8 dot-product instruction (AVX-VNNI or AVX512-VNNI; AMX implies the latter)."""
    return bool({"avx_vnni", "avx512_vnni"} & set(cpu_flags()))


def cpu_has_bf16() -> bool:
    """Whether this CPU computes bf16 natively (AVX512-BF16 or AMX): otherwise bf16 autocast is emulated, slower."""
    return bool({"avx512_bf16", "amx_bf16"} & set(cpu_flags()))


@functools.cache
def git_commit(repo: Path | None = None) -> str | None:
    """The commit of the working tree bcbench runs from, with '-dirty' if it has changes.

    Read once per process (at its first result) and kept: a study that runs for hours stamps every result
    with the code it started with, not with whatever the tree holds when each file is written. Where the files were
    copied to another machine (a lent GPU), the copy's git folder may be a stale snapshot or absent: the launcher
    then declares the commit it copied in $BCBENCH_COMMIT, which wins (scripts/gpu_check.sh sets it).
    """
    if os.environ.get("BCBENCH_COMMIT"):
        return os.environ["BCBENCH_COMMIT"]
    repo = repo or Path(__file__).resolve().parents[3]
    try:
        sha = subprocess.run(
            ["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


# Versions the code was checked against: the exact reset relies on gym-pusht's PushTEnv internals
# (`_set_state`, `_get_coverage`), the samplers on diffusers' scheduler formulas and timestep spacing.
KNOWN_GOOD = {"gym-pusht": ("0.1.8",), "diffusers": ("0.42.1",)}


def require_known_version(package: str) -> None:
    """Fail with one clear line when `package` is at a version bcbench was not checked against."""
    try:
        have = metadata.version(package)
    except metadata.PackageNotFoundError:
        raise BCBenchError(f"{package} is not installed (run `make install`)") from None
    if have not in KNOWN_GOOD[package] and not os.environ.get("BCBENCH_ALLOW_UNTESTED_VERSIONS"):
        raise BCBenchError(f"{package} {have} is not a version bcbench was checked against "
                           f"({', '.join(KNOWN_GOOD[package])}); install that one (`make install`) or set "
                           "BCBENCH_ALLOW_UNTESTED_VERSIONS=1 to try anyway")


def versions() -> dict[str, str | None]:
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def hardware(device: str | None = None) -> dict[str, Any]:
    """The machine, and the device the measured work ran on (a GPU's name only when it ran there)."""
    import torch  # imported here so that data-only commands start fast

    device = device or "cpu"
    info: dict[str, Any] = {
        "device": device,
        **cpu_record(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "platform": platform.platform(),
        "gpu": None,
    }
    if device.startswith("cuda") and torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(torch.device(device))
    return info


def provenance(device: str | None = None) -> dict[str, Any]:
    """Everything a result file records about where it came from: commit (and whether the tree was clean),
    the device the work ran on, library versions."""
    commit = git_commit()
    return {"git_commit": commit, "git_clean": None if commit is None else not commit.endswith("-dirty"),
            "hardware": hardware(device), "versions": versions()}


# ------------------------------------------------------------------ was the machine quiet while we timed?
CONTENDED_CPUS = 0.1  # other processes' CPU use (in CPUs) above which a timing is flagged as not from a quiet machine


def machine_cpu_seconds() -> tuple[float, float] | None:
    """(busy, steal) CPU seconds of the whole machine since boot, summed over its CPUs, from /proc/stat's first
    line (user nice system idle iowait irq softirq steal ...); None where it cannot be read (not Linux)."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    except OSError:
        return None
    if not fields or fields[0] != "cpu" or len(fields) < 9:
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in fields[1:9])
    tick = os.sysconf("SC_CLK_TCK")
    return (user + nice + system + irq + softirq) / tick, steal / tick


def own_cpu_seconds() -> float:
    """CPU seconds of this process (all its threads) and of its children that it has waited for."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class CpuContention:
    """What else used this machine's CPUs during a `with` block: the machine's busy CPU time minus this process's
    own (all its threads, and the child processes it waited for), per second of wall time, in CPUs; and the
    hypervisor's steal time likewise (a VM's neighbours). A timing is only a quiet-machine timing when both are
    near 0: the record keeps them, so a reader can check the brief's rule (never report a timing taken while
    something else ran) instead of trusting it. Resolution is the kernel's tick (10 ms), so blocks under a second
    read coarsely. A policy in a worker process of its own (a LeRobot sidecar) counts as "other": its record says
    it timed itself (`timed_as`)."""

    def __enter__(self) -> CpuContention:
        self._machine0, self._self0, self._t0 = machine_cpu_seconds(), own_cpu_seconds(), time.perf_counter()
        self.result: dict[str, float] | None = None
        return self

    def __exit__(self, *exc: object) -> None:
        machine1, self1, wall = machine_cpu_seconds(), own_cpu_seconds(), time.perf_counter() - self._t0
        if self._machine0 is None or machine1 is None or wall <= 0:
            return
        busy, steal = (b - a for a, b in zip(self._machine0, machine1, strict=True))
        other = max(0.0, busy - (self1 - self._self0))
        self.result = {"other_cpus": round(other / wall, 3), "steal_cpus": round(steal / wall, 3),
                       "seconds": round(wall, 3)}

    def warn(self, what: str) -> None:
        """One line on stderr when other processes (or the VM's neighbours) used more than CONTENDED_CPUS."""
        r = self.result
        if r and max(r["other_cpus"], r["steal_cpus"]) > CONTENDED_CPUS:
            print(f"bcbench: warning: while timing {what}, other processes used {r['other_cpus']:.2f} CPUs and the "
                  f"hypervisor stole {r['steal_cpus']:.2f} (of {os.cpu_count()}): not a quiet-machine timing "
                  "(recorded as cpu_contention)", file=sys.stderr)


def scheduling() -> tuple[int, int] | None:
    """The calling thread's scheduling policy and priority (os.SCHED_OTHER, 0 for an ordinary thread); None where
    Python has no POSIX scheduling calls (macOS, Windows)."""
    if not hasattr(os, "sched_getscheduler"):
        return None
    return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority


def restore_scheduling(was: tuple[int, int] | None) -> bool:
    """Put the calling thread back to `was` (from `scheduling()`) if it changed since; True if it had. Lowering a
    thread's own priority needs no privilege."""
    if was is None or scheduling() == was:
        return False
    os.sched_setscheduler(0, was[0], os.sched_param(was[1]))
    return True
