"""python -m benchmarks: see run.py (what is measured, results.json keys)."""

import sys

from .run import main

sys.exit(main())
