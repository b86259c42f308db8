"""The designs shipped in examples/designs (built by ``jaxflex optimize --servo``): each is what
``--init`` continues from, and its controller files agree with the library's model of the robot
and servo they were built for, so a file gone stale after a change of the model or of the gain rule
fails here."""
import csv
import json
from pathlib import Path

import numpy as np
import pytest

DESIGNS = Path(__file__).resolve().parents[1] / "examples" / "designs"
CASES = sorted(p for p in DESIGNS.iterdir() if p.is_dir())


def _csv(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0], np.asarray(rows[1:], dtype=float)


@pytest.mark.parametrize("case", CASES, ids=[p.name for p in CASES])
def test_a_shipped_design_is_what_init_starts_from_and_its_export_fits_the_model(case):
    """``--init`` of the record starts from its refined design (both corners, every coefficient);
    the controller file holds the default gain rule's gains for that robot, bandwidth, rate and
    rotor (Kp = J (2 pi fc)^2, Kd = 2 0.7 J 2 pi fc, to 1e-9); the CSV runs from the pick to the
    place at rest, its joint angles the IGM of its points (1e-9 rad), at the file's rate over tf,
    and its torque at the pick, at rest, is the static torque of the model at the pick within the
    links' sag (2 %)."""
    from jaxflex.experiments.io import initial_design
    from jaxflex.path import make_path
    from jaxflex.rigid import rigid_torques
    from jaxflex.robot import cycle_preset, igm, robot_preset
    from jaxflex.servo import servo_from_bandwidth

    rec = json.loads((case / "optimize.json").read_text())
    refined = rec["closed_loop"]["refined"]["design"]
    x = initial_design(case / "optimize.json", rec["design"]["path"]["blend"], int(rec["design"]["order"]))
    np.testing.assert_array_equal(np.asarray(x.coef), refined["coef"])
    np.testing.assert_array_equal(np.asarray(x.d), [c["d_m"] for c in refined["corners"]])

    ctrl = json.loads((case / "controller.json").read_text())
    payload, tf = rec["payloads"][0], rec["tf"]
    robot, cycle = robot_preset("default", payload=payload), cycle_preset()
    servo = servo_from_bandwidth(robot, make_path(cycle, "lame", 0.025), ctrl["fc"], rate=ctrl["rate"],
                                 rotor_inertia=ctrl["rotor_inertia"])
    np.testing.assert_allclose(ctrl["kp"], np.asarray(servo.kp), rtol=1e-9)
    np.testing.assert_allclose(ctrl["kd"], np.asarray(servo.kd), rtol=1e-9)

    head, rows = _csv(case / "trajectory.csv")
    assert head == ctrl["columns"] and ctrl["tf"] == tf
    np.testing.assert_allclose(np.diff(rows[:, 0]), 1.0 / ctrl["csv_rate"], rtol=1e-9)
    assert rows[-1, 0] == pytest.approx(tf, rel=1e-12)
    np.testing.assert_allclose(rows[0, 1:3], cycle.pick, atol=1e-12)
    np.testing.assert_allclose(rows[-1, 1:3], cycle.place, atol=1e-12)
    np.testing.assert_array_equal(rows[[0, -1], 5:9], 0.0)
    for i in (0, len(rows) // 3, len(rows) - 1):
        np.testing.assert_allclose(rows[i, 3:5], np.asarray(igm(robot, rows[i, 1:3])), atol=1e-9)
    static = np.asarray(rigid_torques(robot.replace(rotor_inertia=ctrl["rotor_inertia"]), rows[0, 3:5],
                                      np.zeros(2), np.zeros(2)))
    np.testing.assert_allclose(rows[0, 9:11], static, rtol=0.02, atol=0.02 * np.max(np.abs(static)))


def test_reproduce_finds_the_shipped_design_of_each_case_and_bandwidth(tmp_path):
    """``jaxflex reproduce`` evaluates the shipped designs: each paper case's, keyed by the bandwidth
    it was refined at, none for a payload or cycle time without one; a directory without a refined
    design (a perfect-controller run) is passed over, and a missing directory gives none."""
    from jaxflex.experiments import closed_loop as cl

    assert {fc: p.name for fc, p in cl.shipped_designs(6.0, 0.43).items()} == {15.0: "6kg_0.43s_15hz",
                                                                          40.0: "6kg_0.43s_40hz"}
    assert {fc: p.name for fc, p in cl.shipped_designs(0.1, 0.3).items()} == {15.0: "0.1kg_0.3s_15hz",
                                                                           40.0: "0.1kg_0.3s_40hz"}
    assert cl.shipped_designs(6.0, 0.3) == {} and cl.shipped_designs(2.0, 0.43) == {}
    assert cl.shipped_designs(6.0, 0.43, tmp_path / "none") == {}
    rec = json.loads((DESIGNS / "6kg_0.43s_15hz" / "optimize.json").read_text())
    (tmp_path / "plain").mkdir()
    (tmp_path / "plain" / "optimize.json").write_text(json.dumps({k: v for k, v in rec.items() if k != "closed_loop"}))
    assert cl.shipped_designs(6.0, 0.43, tmp_path) == {}
    sh = cl.shipped_design(DESIGNS / "6kg_0.43s_15hz")
    assert (sh["trained_at_hz"], sh["blend"], sh["order"]) == (15.0, rec["design"]["path"]["blend"],
                                                               rec["design"]["order"])
    assert sh["design"] == rec["closed_loop"]["refined"]["design"]


def test_reproduce_evaluates_at_each_bandwidth_the_design_refined_there_or_at_the_nearest(tmp_path, monkeypatch):
    """The closed-loop section's wiring (``closed_loop.shipped_case``), the studies themselves replaced
    by a stand-in: given only the 6 kg design refined at 15 Hz, at 15 Hz it is evaluated under a
    15 Hz servo; at 40 Hz, where none was refined, the same design under a 40 Hz servo (its controller's rate, rotor
    and feedforward), never refined again (no steps); the record names it, and the report says so."""
    from jaxflex.experiments import closed_loop as cl
    from jaxflex.experiments.report import closed_loop_section

    calls = []

    def study(robot, cycle, payload, tf, dwell, grid, x, law, controller, **kw):
        calls.append((payload, tf, controller, kw["steps"], kw["fcs"], np.asarray(x.coef).tolist(), kw["blend"]))
        row = {"perfect_um": 1.0, "nominal_um": 1.0, "box_worst_um": 1.0, "p95_um": 1.0, "max_torque_nm": 1.0,
               "ratio_best_paper_nominal": 1.0, "ratio_best_paper_worst": 1.0, "box_unstable": 0, "box_models": 1}
        return {"controller": controller._asdict(), "samples": kw["samples"], "corners": kw["corners"],
                "paper": {f"{controller.fc:g}": {"best": "polar/poly7"}}, "fcs": {f"{controller.fc:g}": {"optimized": row}}}

    monkeypatch.setattr(cl, "closed_loop_study", study)
    monkeypatch.setattr(cl, "bandwidth_sweep", lambda record, closed, fcs: {"fcs": list(fcs), "dwell_residual_um": {}})
    monkeypatch.setattr(cl, "figure", lambda *a: None)
    monkeypatch.setattr("jaxflex.experiments.io.save_figure", lambda fig, path: None)
    rec = json.loads((DESIGNS / "6kg_0.43s_15hz" / "optimize.json").read_text())
    res = cl.shipped_case({"payloads": [6.0], "tf": 0.43, "first_mode_hz": [58.0]}, str(tmp_path), samples=3,
                          designs={15.0: cl.shipped_design(DESIGNS / "6kg_0.43s_15hz")}, fcs=(15.0, 40.0), figure_fcs=(15.0,))
    refined = rec["closed_loop"]["refined"]["design"]["coef"]
    c = rec["closed_loop"]["controller"]
    assert [(k[2].fc, k[2].rate, k[2].rotor, k[2].feedforward) for k in calls] == [
        (15.0, c["rate"], c["rotor"], c["feedforward"]), (40.0, c["rate"], c["rotor"], c["feedforward"])]
    assert all(k[:2] == (6.0, 0.43) and k[3] == 0 and k[4] == (k[2].fc,) and k[5] == refined
               and k[6] == rec["design"]["path"]["blend"] for k in calls)
    assert [st["shipped"]["trained_at_hz"] for st in res["studies"].values()] == [15.0, 15.0]
    text = closed_loop_section({"cases": [{"dir": "closed_loop_6kg", "payload": 6.0, "tf": 0.43, **res}]})
    assert "fc 40 Hz, the shipped design `examples/designs/6kg_0.43s_15hz` (refined at 15 Hz)" in text
    assert "evaluated here, not refined again" in text
