"""The model-simplification part of the σ: how far a simplified model's torques are from the
anatomical reference, per DOF, as the paper's analysis measured it.

Source: results/paper/results.json (`reproduce_paper`, forearm_dynamics/analysis/), key
models.<placement>.<size>.movements[*].rmse: per movement and DOF, the RMSE (N·m) of the
model's torques against the OpenSim anatomical reference (MoBL-ARMS, radius about the
ulna), both low-passed at 6 Hz, 65 movements. The σ part is the RMS of those over the
movements (sqrt of the mean MSE): a constant per DOF, for the model's placement and body
size. A constant, not a function of the state: the analysis stores one RMSE per movement,
and what it shows varying (the elbow's COM offset, the pro/sup axis) is posture-driven and
small against its spread across movements; a per-state law would be a fit on 65 numbers
per DOF with nothing held out to check it.

The table is copied into the package (data/model_term.json, so an installed node needs no
source tree) by `python -m forearm_dynamics.uncertainty.model_term`; test_uncertainty.py
checks that the copy equals what results.json gives. Anatomical model: 0 (it is the
reference). Sizes other than the 5th/50th/95th percentile men, and placements not in the
table (custom split or offsets): the largest value over the table's sizes (resp.
placements and sizes), said in the source text.
"""

from __future__ import annotations

import json
import math
import sys
from importlib import resources
from pathlib import Path

import numpy as np

TABLE = "model_term.json"
RESULTS = Path("results/paper/results.json")


def table_from_results(results: dict) -> dict:
    """{placement: {size: {dof: σ N·m}}} from reproduce_paper's results.json."""
    out: dict = {}
    for placement, sizes in results["models"].items():
        for size, body in sizes.items():
            mvs = body.get("movements")
            if not mvs:
                continue
            dofs = list(mvs[0]["rmse"])
            out.setdefault(placement, {})[size] = {
                d: math.sqrt(float(np.mean([m["rmse"][d] ** 2 for m in mvs]))) for d in dofs}
    return out


def load_table() -> dict:
    return json.loads(resources.files("forearm_dynamics").joinpath("data", TABLE).read_text())


def model_variance(arm) -> tuple[np.ndarray, str]:
    """(σ_model² per DOF (nv,) N·m², one line saying where it comes from)."""
    n = len(arm.joint_names)
    if arm.kind == "anatomical":
        return np.zeros(n), "anatomical model: it is the reference, no simplification term"
    doc = load_table()
    table = doc["table"]
    placement = arm.placement.name if arm.placement is not None else arm.kind
    size = arm.body_size.label
    if placement in table and size in table[placement]:
        rows, what = [table[placement][size]], f"{placement}, {size}"
    elif placement in table:
        rows = list(table[placement].values())
        what = f"{placement}, largest over {', '.join(table[placement])}"
    else:
        rows = [r for p in table.values() for r in p.values()]
        what = f"placement {placement!r} not in the table: largest over every placement and size"
    sigma = np.array([max(r[d] for r in rows) for d in arm.joint_names])
    return sigma**2, f"{doc['source']} ({what})"


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    src = Path(args[0]) if args else RESULTS
    results = json.loads(src.read_text())
    doc = {"source": "results/paper/results.json models.<placement>.<size>.movements[*].rmse, "
                     "RMS over the 65 movements vs the OpenSim anatomical reference (6 Hz)",
           "command": results.get("command", ""),
           "table": table_from_results(results)}
    out = Path(__file__).resolve().parents[1] / "data" / TABLE
    out.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
