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
from .common import body_size_arg, die


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="export_urdf", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", choices=MODEL_KINDS, default="segmented")
    p.add_argument("--body-size", type=body_size_arg, default=50,
                   help="5, 50 or 95 (percentile), or stature_m,body_mass_kg e.g. 1.80,75")
    p.add_argument("--split", type=float, default=None, help="segmented model split fraction")
    p.add_argument("-o", "--output", default="-", help="output file ('-' = stdout)")
    args = p.parse_args(argv)
    overrides = {} if args.split is None else {"split": args.split}
    try:
        urdf = build_model(args.model, body_size=args.body_size, **overrides).to_urdf()
    except ValueError as exc:
        return die(f"export_urdf: {exc}")
    if args.output == "-":
        sys.stdout.write(urdf)
        return 0
    out = Path(args.output)
    try:
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(urdf, encoding="utf-8")
        tmp.replace(out)
    except OSError as exc:
        return die(f"export_urdf: cannot write {out}: {exc.strerror or exc}")
    print(f"wrote {out} ({args.model}, body size {args.body_size})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
