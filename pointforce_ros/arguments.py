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

MAX_POKES = 1000
"""Most pokes one command may be asked for (the simulated cell takes seconds a poke and holds
a generated campaign in memory: 10^9 pokes took 15 GB in 40 s before any poke was made)."""

MIN_REPLAY_RATE = 1e-3
"""Slowest replay speed-up factor (a slower one turns seconds of bag into days)."""


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


def poke_count(text: str) -> int:
    """Parse a number of pokes: a whole number in 0..MAX_POKES (0: the command's default)."""
    return _int(text, 0, MAX_POKES)


def positive_int(text: str) -> int:
    """Parse a whole number >= 1."""
    return _int(text, 1)


def seed(text: str) -> int:
    """Parse a random seed: a whole number in 0..2**32-1."""
    return _int(text, 0, SEED_MAX)


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a number') from None


def positive_float(text: str) -> float:
    """Parse a finite number > 0 (a length, a rate, a time budget)."""
    value = _float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f'{value} is not a finite number > 0')
    return value


def replay_rate(text: str) -> float:
    """Parse a replay speed-up factor: a finite number >= MIN_REPLAY_RATE."""
    value = _float(text)
    if not (math.isfinite(value) and value >= MIN_REPLAY_RATE):
        raise argparse.ArgumentTypeError(f'{value} is not a finite number >= {MIN_REPLAY_RATE:g}')
    return value
