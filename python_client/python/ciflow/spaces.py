"""Conversions between the engine's wire values and numpy/Gymnasium objects."""

from __future__ import annotations

import math
import os

import numpy as np
from gymnasium import spaces

from ciflow import _native

_OPTION_FIELDS = ("context", "initial_position", "initial_velocity")


def box(space: dict) -> spaces.Box:
    """A Gymnasium ``Box`` from the engine's ``{low, high, dtype}``."""
    dtype = np.dtype(space["dtype"])
    return spaces.Box(
        low=np.asarray(space["low"], dtype=dtype),
        high=np.asarray(space["high"], dtype=dtype),
        dtype=dtype,
    )


def to_wire(values) -> bytes:
    """Little-endian float64 bytes of a 1-D (or row-major 2-D) array."""
    array = np.ascontiguousarray(values, dtype="<f8")
    return array.tobytes()


def actions_to_wire(actions, shape: tuple, layout: str) -> bytes:
    """``actions`` as :func:`to_wire` bytes, refused unless of exactly ``shape`` (as
    ``Box.contains`` would): a reshape would pair numbers with the wrong environment or
    joint. ``layout`` says what the shape holds, for the message."""
    array = np.asarray(actions, dtype="<f8")
    if array.shape != shape:
        raise ValueError(f"actions of shape {array.shape}; this environment takes {shape} "
                         f"({layout})")
    return to_wire(array)


def from_wire(data: bytes | bytearray, dtype, shape=None) -> np.ndarray:
    """Little-endian ``f64`` bytes as a writable array of ``dtype`` that owns its values:
    a ``bytearray`` is read in place, ``bytes`` (read-only) are copied."""
    array = np.frombuffer(data, dtype="<f8")
    if shape is not None:
        array = array.reshape(shape)
    return array.astype(dtype, copy=not isinstance(data, bytearray))


def seed_value(value) -> int:
    """A seed as the engines take it: a whole number from 0 to 2⁶⁴ − 1."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or not 0 <= int(value) < 2**64:
        raise ValueError(f"a seed is a whole number from 0 to 2**64 - 1, not {value!r}")
    return int(value)


def reset_options(defaults: dict, options: dict | None) -> dict | None:
    """Reset options as the engine takes them: known fields as lists of floats,
    everything else in ``extra`` (task-specific numbers such as ``obstacles``)."""
    merged = dict(defaults)
    merged.update(options or {})
    if not merged:
        return None
    wire: dict = {"extra": {}}
    for key, value in merged.items():
        if value is None:
            continue
        if key in _OPTION_FIELDS:
            wire[key] = [float(v) for v in np.asarray(value, dtype=float).ravel()]
        elif key == "extra":
            wire["extra"].update({k: float(v) for k, v in value.items()})
        else:
            wire["extra"][key] = float(value)
    return wire


def construction_kwargs(task: str, kwargs: dict) -> dict:
    """The task's construction arguments as the engine takes them: numbers as floats, and
    strings as the task reads them — a name of a value (LASA's ``shape="Sshape"``), a text
    (the reach task's ``tool``), or a document given by path (its ``urdf``), read here so
    that the environment's identity holds the content, not this machine's path."""
    arguments = {}
    for key, value in kwargs.items():
        if isinstance(value, os.PathLike):
            value = os.fspath(value)
        if isinstance(value, str):
            arguments[key] = _native.task_argument(task, key, value)
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value):
                raise ValueError(f"task argument {key}={value!r} is not finite")
            arguments[key] = float(value)
        else:
            raise TypeError(f"task argument {key}={value!r}: expected a number or a string")
    return arguments
