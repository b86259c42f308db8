"""The names a user chooses from: robot presets, blend families and motion laws. Plain Python (no
JAX), so that the command line can offer them without importing the library's numerics."""

PRESETS = ("default", "table6")                         # robot presets (docs/conventions.md#frames-and-geometry)
BLENDS = ("lame", "clothoid", "polar")                  # the paper's blend families
SMOOTH_BLENDS = ("smoothstep", "polar_g3", "polar_g4")  # more continuity at the joins (not in the paper)
ALL_BLENDS = BLENDS + SMOOTH_BLENDS
DESIGN_BLENDS = ("lame", "polar") + SMOOTH_BLENDS      # families whose (d, e) may be chosen freely
PROFILES = ("poly7", "bang_bang", "trap_1_4", "trap_1_8")   # the paper's motion laws
