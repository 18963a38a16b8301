"""Steal time of each vCPU (time the host ran something else), sampled from /proc/stat every
5 ms: the total, and how it came (a jump of k ticks of 10 ms between two samples is a pause
of about k·10 ms). docs/testing.md quotes it with and without a disk writer beside it:

    python -m benchmarks.vcpu_steal --seconds 60
    (while: dd if=/dev/zero of=/tmp/junk bs=1M count=3000 conv=fsync, in a loop)
"""

from __future__ import annotations

import argparse
import os
import time


def _steal() -> dict[str, int]:
    """Steal ticks (USER_HZ, 10 ms) per CPU, from /proc/stat's 8th value."""
    out = {}
    with open("/proc/stat") as f:
        for line in f:
            if line.startswith("cpu") and line[3] != " ":
                fields = line.split()
                out[fields[0]] = int(fields[8])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args(argv)
    prev, end = _steal(), time.monotonic() + args.seconds
    total: dict[str, int] = dict.fromkeys(prev, 0)
    jumps: dict[str, dict[int, int]] = {c: {} for c in prev}
    while time.monotonic() < end:
        time.sleep(0.005)
        cur = _steal()
        for cpu, ticks in cur.items():
            if d := ticks - prev[cpu]:
                total[cpu] += d
                jumps[cpu][d] = jumps[cpu].get(d, 0) + 1
        prev = cur
    print(f"steal over {args.seconds:g} s, ticks of 10 ms per CPU: {total}; jumps (ticks: how "
          f"often): { {c: dict(sorted(j.items())) for c, j in jumps.items()} }; load average "
          f"{os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
