"""Argument types of the command lines: a number outside its range is refused as it is parsed.

Without them a negative poke count or seed, a zero repeat count or a NaN mesh size starts the
job (the demo's cell takes a minute) and ends in a traceback or in a message about something
else; with them argparse answers at once: ``error: argument --pokes: -1 is not >= 0``.
"""

import argparse
import math
from typing import Optional

SEED_MAX = 2 ** 32 - 1
"""Largest seed the command lines take (numpy's generators take any integer from 0)."""


def _int(text: str, low: int, high: Optional[int] = None) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a whole number') from None
    if value < low or (high is not None and value > high):
        span = f'>= {low}' if high is None else f'in {low}..{high}'
        raise argparse.ArgumentTypeError(f'{value} is not {span}')
    return value


def count(text: str) -> int:
    """Parse a whole number >= 0 (a count where 0 means "the default" or "none")."""
    return _int(text, 0)


def positive_int(text: str) -> int:
    """Parse a whole number >= 1."""
    return _int(text, 1)


def seed(text: str) -> int:
    """Parse a random seed: a whole number in 0..2**32-1."""
    return _int(text, 0, SEED_MAX)


def positive_float(text: str) -> float:
    """Parse a finite number > 0 (a length, a rate, a time budget)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a number') from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f'{value} is not a finite number > 0')
    return value
