"""Argument types shared by the CLI commands: a number out of its range is refused by argparse, with the
option named, before anything starts (no command takes a negative time or NaN for a duration)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

MAX_SECONDS = 86_400.0  # a day: beyond that a duration is a typo


def seconds(text: str) -> float:
    """A duration in seconds, above 0 and at most a day."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (math.isfinite(value) and 0 < value <= MAX_SECONDS):
        raise argparse.ArgumentTypeError(f"{text} is not a duration: give a number of seconds above 0 "
                                         f"(at most {MAX_SECONDS:g})")
    return value


def count(text: str) -> int:
    """A number of things, 1 or more."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} is not a count: give 1 or more")
    return value


def pace(text: str) -> float:
    """A pace factor: 0 (as fast as possible) or a finite positive number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"{text} is not a pace: give 0 (as fast as possible) or a positive "
                                         "number")
    return value


def bounded_float(lo: float | None, hi: float | None) -> Callable[[str], float]:
    """A finite number within [lo, hi] (either bound may be absent), as a message field allows it."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(value) or (lo is not None and value < lo) or (hi is not None and value > hi):
            span = f"{'-inf' if lo is None else f'{lo:g}'} .. {'inf' if hi is None else f'{hi:g}'}"
            raise argparse.ArgumentTypeError(f"{text} is out of range: give a number in {span}")
        return value

    parse.__name__ = "number"  # argparse names the type in its messages
    return parse
