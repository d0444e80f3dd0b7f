"""Command-line argument types shared by the ``python -m ciflow.…`` scripts."""

from __future__ import annotations

import argparse
import math


def positive_seconds(text: str) -> float:
    """A finite, positive number of seconds (an argparse ``type``)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"`{text}` is not a positive number of seconds")
    return value
