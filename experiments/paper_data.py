"""The paper's published numbers, used ONLY for the "paper" column of comparisons.

Transcribed from ../shared/paper/seed-paper.txt (tables keep the paper's row/column layout:
profile -> blend). Nothing in the library reads this module.
"""

PROFILE_ORDER = ("poly7", "bang_bang", "trap_1_4", "trap_1_8")
BLEND_ORDER = ("lame", "clothoid", "polar")

# Table 2: blend lengths [mm] for d = e = 25 mm (and the "extended" curves).
TABLE2_BLEND_LENGTH_MM = {
    "lame": 42.156, "clothoid": 41.333, "polar": 41.106,
    "lame_extended": 59.307, "clothoid_extended": 57.015,
}


def _by_blend(rows):
    """rows: {profile: (lame, clothoid, polar)} -> {blend: {profile: v}}."""
    return {b: {p: rows[p][i] for p in PROFILE_ORDER} for i, b in enumerate(BLEND_ORDER)}


# Table 5: max task-space acceleration [m/s^2], tf = 1 s.
TABLE5_TASK_ACC = _by_blend({
    "poly7": (7.7818, 7.3686, 7.0384),
    "bang_bang": (5.1687, 4.7268, 4.4662),
    "trap_1_4": (6.8895, 6.2916, 5.9544),
    "trap_1_8": (11.8115, 10.7638, 10.0453),
})

# Table 6: max joint-space acceleration [rad/s^2], tf = 1 s.
TABLE6_JOINT_ACC = _by_blend({
    "poly7": (25.0858, 25.3279, 21.2023),
    "bang_bang": (16.4343, 16.4834, 13.7179),
    "trap_1_4": (21.8879, 21.9759, 18.1215),
    "trap_1_8": (37.432, 37.6681, 30.9457),
})

# Natural frequencies along the path (Section 4): mean +- spread [Hz].
FREQUENCIES_HZ = {
    6.0: {"first": (58.0, 1.0)},
    0.1: {"first": (126.0, 2.0), "third": (1912.0, 7.5)},
}
