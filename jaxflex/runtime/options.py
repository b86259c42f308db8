"""XLA compiler options of the library's programs, by how they are used.

A program compiled once and run many times is worth a slower, more optimizing compilation; one run
once or twice is not. Three kinds (docs/performance.md has the measurements behind each choice):

- ``HOT_LOOP``, the *fast* build: the engine's rollout programs, and an optimizer's value and
  gradient when it runs many steps. LLVM optimization level 1 (as fast at run time as the default
  level 3, and quicker to compile) with XLA's classic elemental emitters. These options override
  XLA_FLAGS for these programs only.
- ``BUILD``: the large programs compiled once per process and run a few to hundreds of times (the
  coefficient program of every table build, the table poses, the locked modes at a point, the
  paper combinations' kinematics, the full model's stepping program): ``HOT_LOOP``, unless
  XLA_FLAGS choose an optimization level themselves (the test suite's level 0).
- ``ONCE``: the large programs run once or twice per call (the full model's start and its outputs
  at the ends): LLVM level 0, unless XLA_FLAGS choose a level themselves.

``build(name)`` maps the one setting an optimizer exposes, its build, to options: "fast"
(``HOT_LOOP``) or "quick" (XLA's options of the process: quicker to compile; smoke runs and
gradient checks).
"""
from __future__ import annotations

import os

HOT_LOOP = {"xla_backend_optimization_level": 1, "xla_cpu_use_fusion_emitters": False}

_LEVEL_IN_FLAGS = "xla_backend_optimization_level" in os.environ.get("XLA_FLAGS", "")

BUILD = None if _LEVEL_IN_FLAGS else HOT_LOOP

ONCE = None if _LEVEL_IN_FLAGS else {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}

BUILDS = ("quick", "fast")


def build(name: str) -> dict | None:
    """The compiler options of the build ``name`` ("quick": None, the process's options; "fast":
    ``HOT_LOOP``)."""
    if name not in BUILDS:
        raise ValueError(f"build must be one of {BUILDS}, got {name!r}")
    return HOT_LOOP if name == "fast" else None
