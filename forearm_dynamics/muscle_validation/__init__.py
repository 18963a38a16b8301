"""The muscle layer checked against independent engines (issue 31, item 5).

- `opensim_so.py` — OpenSim's StaticOptimization on our skeleton with the shipped muscles
  (DeGrooteFregly2016 muscles whose FunctionBasedPaths hold the surrogate polynomials).
- `reference.py` — the cached result of `make muscle-reference` (OpenSim SO and the
  exact-geometry solve: MuJoCo tendon Jacobians + scipy BVLS) and the per-muscle comparison
  the tests and benchmarks/muscle_node.py make with it.

Why a package of its own (beside offline/, layer 6): it combines the muscle layer, OpenSim's
table files (formats/) and the engines, and nothing at run time needs it.
"""
