"""What every benchmark reports the same way: percentiles, machine facts, the results file.

benchmarks/results.json is shared by several benchmarks (`python -m benchmarks` writes
compute, torque_path, choices, recorder, offline, goals; others add their own section):
each writes only its own top-level keys and keeps the others (read-modify-write), with
`sections.<key>` = {command, started} saying which run produced each.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np

from forearm_dynamics.processes import DomainLease, claim_domain


def claim_domain_arg(ap: argparse.ArgumentParser, domain: int, prog: str) -> DomainLease:
    """The benchmark's --domain, held for the run (processes.claim_domain: moved, and said
    so, when another run holds it); an id outside 1..232 is a usage error."""
    try:
        return claim_domain(domain, prog)
    except ValueError as exc:
        ap.error(str(exc))


def percentiles(values, scale: float = 1.0) -> dict[str, float]:
    """{n, p50, p99, p99_9, max, mean} of `values` * scale; {n: 0} when there are none."""
    v = np.asarray(values, float) * scale
    if v.size == 0:
        return {"n": 0}
    p50, p99, p999 = np.percentile(v, [50, 99, 99.9])
    return {"n": int(v.size), "p50": float(p50), "p99": float(p99), "p99_9": float(p999),
            "max": float(v.max()), "mean": float(v.mean())}


def serving_period(values: dict) -> bool:
    """A node's /diagnostics period (its key/value strings) in which it answered: its
    callback figures are about the stream (receiver.py announces them, torque_path.py
    takes them)."""
    try:
        return float(values.get("output_rate_hz", 0)) > 0 and values.get("compute_us_p50", "nan") != "nan"
    except ValueError:
        return False


def loadavg() -> list[float] | None:
    """1, 5 and 15-minute load averages (2 cores: above ~1.5 someone else is busy too)."""
    try:
        return list(os.getloadavg())
    except OSError:
        return None


def machine_info() -> dict:
    info = {"machine": platform.machine(), "cores": os.cpu_count(),
            "python": platform.python_version(), "platform": platform.platform()}
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return info


def merge_results(path: Path, new: dict, provenance: dict, sections: list[str] | None = None) -> dict:
    """The results file at `path` with the keys of `new` replaced (others kept as they were).

    `provenance` ({command, started}) is recorded under `sections.<key>` for every key in
    `sections` (default: every key of `new`). A missing or unreadable file starts empty.
    """
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        old = {}
    if not isinstance(old, dict):
        old = {}
    merged = {**old, **new}
    record = dict(old.get("sections") or {})
    record.update({key: dict(provenance) for key in (new if sections is None else sections)})
    merged["sections"] = record
    return merged


def save_sections(path: Path, new: dict, script: str, argv: list[str] | None, started: str) -> None:
    """Merge `new` into the results file at `path` (merge_results), each key recorded with the
    command that made it (`python <script> <argv>`) and when it started."""
    cmd = f"python {script} " + " ".join(argv if argv is not None else sys.argv[1:])
    write_json(path, merge_results(path, new, {"command": cmd.strip(), "started": started}))


def write_json(path: Path, data: dict) -> None:
    """Write atomically (a reader never sees half a file; another section's writer loses nothing)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=1, default=float) + "\n", encoding="utf-8")
    os.replace(tmp, path)
