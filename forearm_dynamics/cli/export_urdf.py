"""export_urdf: write one model as URDF, for RViz, Foxglove or any other engine.

Exactly the model's inertias, joint axes and limits, and a <visual> and <collision> for every
body (the uniform solid of its own inertia, with a material), so the arm is visible.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .. import build_model
from ..builders import MODEL_KINDS
from ..exit_codes import OK
from .common import body_size_arg, die, numbers_arg


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="export_urdf", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", choices=MODEL_KINDS, default="segmented")
    p.add_argument("--body-size", type=body_size_arg, default=50,
                   help="5, 50 or 95 (men's percentile), male_5 ... female_95, or "
                        "stature_m,body_mass_kg e.g. 1.80,75")
    p.add_argument("--side", choices=("right", "left"), default="right",
                   help="which arm (left = the mirror image, same joint names and signs)")
    p.add_argument("--split", type=float, default=None, help="segmented model split fraction")
    p.add_argument("--payload-mass", type=float, default=0.0, help="object in the hand, kg")
    p.add_argument("--payload-com", type=numbers_arg(3, "x,y,z in m (hand frame)"), default=None,
                   help="its centre of mass x,y,z in m in the hand frame (default: power grasp); "
                        "write --payload-com=-0.01,... when x is negative")
    p.add_argument("--payload-inertia", default=None,
                   type=numbers_arg(6, "Ixx,Iyy,Izz,Ixy,Ixz,Iyz in kg·m²"),
                   help="its inertia about its COM, Ixx,Iyy,Izz,Ixy,Ixz,Iyz (default: point mass)")
    p.add_argument("-o", "--output", default="-", help="output file ('-' = stdout)")
    args = p.parse_args(argv)
    overrides = {} if args.split is None else {"split": args.split}
    try:
        urdf = build_model(args.model, body_size=args.body_size, side=args.side,
                           payload_mass=args.payload_mass, payload_com=args.payload_com,
                           payload_inertia=args.payload_inertia, **overrides).to_urdf()
    except ValueError as exc:
        return die(f"export_urdf: {exc}")
    if args.output == "-":
        sys.stdout.write(urdf)
        return OK
    out = Path(args.output)
    try:
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(urdf, encoding="utf-8")
        tmp.replace(out)
    except OSError as exc:
        return die(f"export_urdf: cannot write {out}: {exc.strerror or exc}")
    payload = f", payload {args.payload_mass:g} kg" if args.payload_mass else ""
    print(f"wrote {out} ({args.model}, {args.side} arm, body size {args.body_size}{payload})",
          file=sys.stderr)
    return OK


if __name__ == "__main__":
    sys.exit(main())
