"""The paper's published numbers, used ONLY for the "paper" column of comparisons.

Transcribed from the paper, *Trajectory generation for high speed pick and place robots* (tables
keep the paper's row/column layout: profile -> blend). Nothing in the library reads this module.
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

# Table 7 (6 kg, tf = 0.43 s) and Table 9 (0.1 kg, tf = 0.3 s): along the motion.
TABLE7 = {
    "max_torque_nm": _by_blend({"poly7": (73.634, 70.046, 71.298), "bang_bang": (56.084, 50.848, 50.734),
                                "trap_1_4": (75.208, 74.605, 62.496), "trap_1_8": (125.45, 124.45, 119.16)}),
    "rms_acc_error": _by_blend({"poly7": (2.7168, 3.3724, 6.641), "bang_bang": (4.5245, 4.7786, 5.4098),
                                "trap_1_4": (6.0193, 6.3989, 8.6868), "trap_1_8": (10.572, 10.731, 13.865)}),
    "max_deflection_mm": _by_blend({"poly7": (0.09700, 0.09226, 0.09392),
                                    "bang_bang": (0.07387, 0.06696, 0.06681),
                                    "trap_1_4": (0.09911, 0.09832, 0.08233),
                                    "trap_1_8": (0.16540, 0.16408, 0.13813)}),
}
TABLE9 = {
    "max_torque_nm": _by_blend({"poly7": (33.6384, 32.737, 33.0867), "bang_bang": (23.9012, 23.1011, 22.3707),
                                "trap_1_4": (30.6662, 29.4722, 28.56), "trap_1_8": (51.3054, 45.9056, 47.4447)}),
    "rms_acc_error": _by_blend({"poly7": (3.3563, 3.8525, 6.2169), "bang_bang": (5.2095, 5.3852, 5.7002),
                                "trap_1_4": (5.2813, 5.6053, 5.9695), "trap_1_8": (9.8592, 8.7226, 9.5968)}),
    "max_deflection_mm": _by_blend({"poly7": (0.04339, 0.04223, 0.04269),
                                    "bang_bang": (0.03082, 0.02979, 0.02885),
                                    "trap_1_4": (0.03957, 0.03802, 0.03684),
                                    "trap_1_8": (0.0663, 0.05931, 0.06134)}),
}
# Table 8 (6 kg) and Table 10 (0.1 kg): residual |e|, |e'|, |e''| at tf.
TABLE8 = {
    "residual_pos_mm": _by_blend({"poly7": (0.9355, 0.0009, 0.3109), "bang_bang": (4.8557, 0.0007, 0.5573),
                                  "trap_1_4": (5.5411, 0.0017, 0.9366), "trap_1_8": (8.7118, 0.0049, 0.2872)}),
    "residual_vel": _by_blend({"poly7": (0.0009, 0.0053, 0.4973), "bang_bang": (0.0049, 0.0050, 1.0716),
                               "trap_1_4": (0.0055, 0.0055, 0.2611), "trap_1_8": (0.0087, 0.0062, 0.8352)}),
    "residual_acc": _by_blend({"poly7": (0.5573, 0.0045, 1.3193), "bang_bang": (0.4973, 0.0087, 3.8472),
                               "trap_1_4": (0.8352, 0.0056, 1.8212), "trap_1_8": (1.8212, 0.0083, 3.0404)}),
}
TABLE10 = {
    "residual_pos_mm": _by_blend({"poly7": (0.0157, 0.0009, 0.3109), "bang_bang": (0.0078, 0.0007, 0.5573),
                                  "trap_1_4": (0.0160, 0.0017, 0.9366), "trap_1_8": (0.0439, 0.0049, 0.2872)}),
    "residual_vel": _by_blend({"poly7": (0.0009, 0.0053, 0.4973), "bang_bang": (0.0049, 0.0050, 1.0716),
                               "trap_1_4": (0.0055, 0.0055, 0.2611), "trap_1_8": (0.0087, 0.0062, 0.8352)}),
    "residual_acc": _by_blend({"poly7": (0.5573, 0.0045, 1.3193), "bang_bang": (0.4973, 0.0050, 1.0716),
                               "trap_1_4": (0.8352, 0.0045, 1.3193), "trap_1_8": (1.8212, 0.0083, 3.0404)}),
}
# Table 11: short vs extended blends (payload and tf not stated by the paper).
TABLE11_COLUMNS = ("lame", "clothoid", "lame_extended", "clothoid_extended")
TABLE11_PATH_LENGTH_M = dict(zip(TABLE11_COLUMNS, (0.3843, 0.3840, 0.3687, 0.3751)))
TABLE11 = {
    "residual_pos_mm": {"poly7": (0.0524, 0.0503, 0.0606, 0.0905), "bang_bang": (0.0219, 0.0293, 0.0125, 0.0461),
                        "trap_1_4": (0.0158, 0.0221, 0.0056, 0.0320), "trap_1_8": (0.0968, 0.0919, 0.0441, 0.0659)},
    "residual_vel": {"poly7": (0.0014, 0.0044, 0.0005, 0.0058), "bang_bang": (0.0085, 0.0102, 0.0007, 0.0039),
                     "trap_1_4": (0.0122, 0.0130, 0.0134, 0.0138), "trap_1_8": (0.0162, 0.0253, 0.0081, 0.0283)},
    "residual_acc": {"poly7": (1.7121, 2.0211, 0.3816, 0.2521), "bang_bang": (1.6179, 2.9177, 0.2230, 0.8533),
                     "trap_1_4": (1.6563, 2.2635, 1.0501, 1.2532), "trap_1_8": (18.1496, 17.4328, 8.9629, 12.2502)},
}
