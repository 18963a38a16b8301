"""make_reference: regenerate the gold-standard torques (anatomical model in OpenSim)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from ..anthropometry import resolve_body_size
from ..builders import build_tree
from ..description import load_description
from ..exit_codes import OK
from ..movements import default_rate_hz, movement_library
from ..reference import REFERENCE_FILE, save_reference
from .common import die

BODY_SIZES = (5, 50, 95)


def reference_torques(body_sizes, movement_ids, rate_hz: float, progress=None) -> np.ndarray:
    """(S, M, N, 20) raw OpenSim inverse dynamics of the anatomical model."""
    from ..opensim_engine import OpenSimArm

    lib = movement_library()
    out = []
    for size in body_sizes:
        arm = OpenSimArm(build_tree("anatomical", load_description(), resolve_body_size(size)))
        per_size = []
        for mid in movement_ids:
            mv = lib[mid - 1]
            per_size.append(arm.inverse_dynamics(*mv.evaluate(mv.sample_times(rate_hz))))
            if progress:
                progress(size, mid)
        out.append(per_size)
    return np.asarray(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="make_reference", description=__doc__)
    p.add_argument("-o", "--output", type=Path, default=REFERENCE_FILE)
    p.add_argument("--rate", type=float, default=default_rate_hz(), help="sampling rate, Hz")
    args = p.parse_args(argv)
    try:
        import opensim
    except ImportError:
        return die("make_reference: needs OpenSim: pip install '.[reference]' (opensim==4.6)")
    ids = [m.id for m in movement_library()]
    t0 = time.perf_counter()

    def progress(size, mid):
        print(f"\rOpenSim inverse dynamics: p{size} movement {mid:2d}/65", end="", file=sys.stderr)

    torques = reference_torques(BODY_SIZES, ids, args.rate, progress)
    meta = {
        "engine": "opensim", "engine_version": str(opensim.__version__), "model": "anatomical",
        "generator": "make reference (forearm_dynamics.cli.make_reference)",
        "filtered": False,
    }
    try:
        save_reference(args.output, torques, BODY_SIZES, ids, args.rate, meta)
    except OSError as exc:
        return die(f"make_reference: cannot write {args.output}: {exc}")
    print(f"\nwrote {args.output} {torques.shape} in {time.perf_counter() - t0:.1f} s",
          file=sys.stderr)
    return OK


if __name__ == "__main__":
    sys.exit(main())
