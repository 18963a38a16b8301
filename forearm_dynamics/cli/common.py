"""Small shared pieces of the command-line tools."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from ..errors import ForearmDynamicsError, OutputExists, exit_code_of
from ..exit_codes import USAGE


def die(message: str, code: int = USAGE) -> int:
    """One clear line on stderr, no traceback; returns the exit code."""
    print(message, file=sys.stderr)
    return code


def guarded(prog: str, run: Callable[[argparse.Namespace], int], args: argparse.Namespace,
            what: str) -> int:
    """run(args), every error one line on stderr with its exit code (errors.exit_code_of).

    what: names the input and the verb for an unexpected error, e.g. "BAG: cannot analyse";
    a bad file must never end in a traceback.
    """
    try:
        return run(args)
    except ForearmDynamicsError as exc:
        hint = ""
        if isinstance(exc, OutputExists) and "exists already" in str(exc) \
                and getattr(args, "overwrite", None) is False:
            hint = " (--overwrite replaces it)"
        return die(f"{prog}: error: {exc}{hint}", exit_code_of(exc))
    except (OSError, ValueError, KeyError) as exc:
        return die(f"{prog}: error: {exc}", USAGE)
    except Exception as exc:  # noqa: BLE001 - a bad file must never end in a traceback
        return die(f"{prog}: error: {what} ({type(exc).__name__}: {exc})", USAGE)


def body_size_arg(text: str):
    """'50' -> 50; 'female_50' -> 'female_50'; '1.80,75' -> {'stature': 1.80, 'body_mass': 75.0}.

    A name is passed on as it is: build_model checks it and says which names exist.
    """
    text = text.strip()
    if "," in text:
        try:
            stature, mass = (float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected stature_m,body_mass_kg, got {text!r}") from None
        return {"stature": stature, "body_mass": mass}
    if text[:1].isalpha() and not text.lower().startswith("p"):
        return text
    try:
        return int(text.removesuffix("th"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected 5, 50, 95, a name such as female_50, or stature,mass; got {text!r}") from None


def numbers_arg(count: int, what: str):
    """An argparse type: `count` comma-separated numbers ('0,-0.06,-0.045')."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) != count:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return values

    return parse
