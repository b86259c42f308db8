"""Eager argument checks shared by every public entry point (docs/conventions.md#bad-input).

Each check runs on the host in plain Python/numpy before anything is traced or compiled, raises a
``ValueError`` that names the argument, and returns the value converted (float, int, tuple). Traced
values (inside ``jax.jit``/``vmap``/``grad``) are not checked: they are returned unchanged.
"""
from __future__ import annotations

import math
import sys
from typing import Iterable, Sequence

import numpy as np


def is_traced(value) -> bool:
    """True if ``value`` (or any leaf of it) is a JAX tracer: eager checks do not apply. (Without
    JAX imported nothing is traced: the configurations that use these checks import no JAX.)"""
    jax = sys.modules.get("jax")
    return jax is not None and any(isinstance(v, jax.core.Tracer) for v in jax.tree_util.tree_leaves(value))


def _scalar(name: str, value, unit: str) -> float:
    if isinstance(value, (str, bytes)) or np.ndim(value) != 0:
        raise ValueError(f"{name} must be a number{unit}, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number{unit}, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite{unit}, got {v}")
    return v


def positive(name: str, value, unit: str = "") -> float:
    """A finite number > 0 (e.g. a time [s], a rate, a step); ``unit`` is appended to the message."""
    if is_traced(value):
        return value
    u = f" [{unit}]" if unit else ""
    v = _scalar(name, value, u)
    if not v > 0:
        raise ValueError(f"{name} must be > 0{u}, got {v:g}")
    return v


def nonnegative(name: str, value, unit: str = "") -> float:
    """A finite number >= 0 (e.g. a payload [kg])."""
    if is_traced(value):
        return value
    u = f" [{unit}]" if unit else ""
    v = _scalar(name, value, u)
    if not v >= 0:
        raise ValueError(f"{name} must be >= 0{u}, got {v:g}")
    return v


def count(name: str, value, minimum: int = 1) -> int:
    """An integer >= ``minimum`` (steps, repeats, coefficients, chunk sizes)."""
    if isinstance(value, bool) or isinstance(value, (str, bytes)) or np.ndim(value) != 0:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}") from None
    if not math.isfinite(v) or v != int(v) or v < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(v)


def one_of(name: str, value, options: Iterable[str]) -> str:
    """A name among ``options``."""
    options = tuple(options)
    if value not in options:
        raise ValueError(f"unknown {name} {value!r}; choose one of {', '.join(map(str, options))}")
    return value


def positives(name: str, values, unit: str = "", *, nonempty: bool = True) -> tuple:
    """A non-empty sequence of finite numbers > 0 (e.g. motion times [s])."""
    seq = _sequence(name, values, nonempty)
    return tuple(positive(f"{name}[{i}]", v, unit) for i, v in enumerate(seq))


def nonnegatives(name: str, values, unit: str = "", *, nonempty: bool = True) -> tuple:
    """A non-empty sequence of finite numbers >= 0 (e.g. payloads [kg])."""
    seq = _sequence(name, values, nonempty)
    return tuple(nonnegative(f"{name}[{i}]", v, unit) for i, v in enumerate(seq))


def _sequence(name: str, values, nonempty: bool) -> Sequence:
    if isinstance(values, (str, bytes)):
        raise ValueError(f"{name} must be a sequence of numbers, got {values!r}")
    seq = [values] if np.ndim(values) == 0 else list(np.asarray(values, dtype=object).ravel())
    if nonempty and not seq:
        raise ValueError(f"{name} must not be empty")
    return seq
