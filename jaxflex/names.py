"""The names a user chooses from: robot presets, blend families and motion laws. Plain Python (no
JAX), so that the command line can offer them without importing the library's numerics."""

PRESETS = ("default", "table6")                         # robot presets (docs/conventions.md#frames-and-geometry)
BLENDS = ("lame", "clothoid", "polar")                  # the paper's blend families
SMOOTH_BLENDS = ("smoothstep", "polar_g3", "polar_g4")  # more continuity at the joins (not in the paper)
ALL_BLENDS = BLENDS + SMOOTH_BLENDS
DESIGN_BLENDS = ("lame", "polar") + SMOOTH_BLENDS      # families whose (d, e) may be chosen freely
PROFILES = ("poly7", "bang_bang", "trap_1_4", "trap_1_8")   # the paper's motion laws

# What figures print for the names above (legends, titles): ``display_name``. Records, JSON and CSV
# keep the code names.
DISPLAY_NAMES = {
    "lame": "Lamé", "clothoid": "clothoid pair", "polar": "polar polynomial",            # blends
    "smoothstep": "smoothstep", "polar_g3": "polar (G3)", "polar_g4": "polar (G4)",
    "lame_extended": "Lamé (extended)", "clothoid_extended": "clothoid pair (extended)",
    "poly7": "7th-degree polynomial", "bang_bang": "bang-bang",                           # motion laws
    "trap_1_4": "trapezoidal 1/4", "trap_1_8": "trapezoidal 1/8", "ruckig": "Ruckig (jerk-limited)",
    "shaped": "shaped", "optimized": "optimized",
}
_SHAPERS = ("+ZVD", "+ZV")             # input-shaped laws: "<law>+ZV", "<law>+ZVD" (jaxflex.profiles)
_SUFFIXES = (" (best paper)",)


def display_name(key: str) -> str:
    """The readable name of a blend family, a motion law or a combination label, for legends and
    titles: ``"trap_1_4"`` -> ``"trapezoidal 1/4"``; a combination ``"blend/law"`` (or
    ``"blend-law"``) -> ``"blend, law"``, where the law may carry a shaper (``"+ZV"``, ``"+ZVD"`` ->
    ``" + ZV"``) and the label the suffix ``" (best paper)"``: ``"lame/trap_1_4+ZVD"`` -> ``"Lamé,
    trapezoidal 1/4 + ZVD"``. Anything else (an unknown name, free text) is returned unchanged."""
    if not isinstance(key, str):
        return key
    if key in DISPLAY_NAMES:
        return DISPLAY_NAMES[key]
    body, suffix = key, ""
    for s in _SUFFIXES:
        if body.endswith(s):
            body, suffix = body[: -len(s)], s
            break
    for sep in ("/", "-"):
        blend, found, law = body.partition(sep)
        if found and blend in DISPLAY_NAMES:
            shown = _law_name(law)
            if shown is not None:
                return f"{DISPLAY_NAMES[blend]}, {shown}{suffix}"
    shown = _law_name(body)
    return key if shown is None else shown + suffix


def _law_name(law: str):
    """A law's readable name, shaper included (``"poly7+ZV"`` -> ``"7th-degree polynomial + ZV"``), or
    None for a name that is not one."""
    shaper = ""
    for s in _SHAPERS:
        if law.endswith(s):
            law, shaper = law[: -len(s)], " + " + s[1:]
            break
    name = DISPLAY_NAMES.get(law)
    return None if name is None else name + shaper
