"""Small shared pieces of the command-line tools."""

from __future__ import annotations

import argparse
import sys

from ..exit_codes import USAGE


def die(message: str, code: int = USAGE) -> int:
    """One clear line on stderr, no traceback; returns the exit code."""
    print(message, file=sys.stderr)
    return code


def body_size_arg(text: str):
    """'50' -> 50; '1.80,75' -> {'stature': 1.80, 'body_mass': 75.0}."""
    text = text.strip()
    if "," in text:
        try:
            stature, mass = (float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected stature_m,body_mass_kg, got {text!r}") from None
        return {"stature": stature, "body_mass": mass}
    try:
        return int(text.removesuffix("th"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 5, 50, 95 or stature,mass; got {text!r}") from None
