"""Robots, cycles and servo settings from TOML files (``jaxflex.robot_files``) and the command line's
--robot, --cycle, --pick/--place/--lift: what a file says is what the model gets, a typo or a pose
the robot cannot take is an error before anything compiles."""
from pathlib import Path

import numpy as np
import pytest

from jaxflex import robot_files as rf
from jaxflex.experiments import cli
from jaxflex.robot import cycle_preset, dgm, igm, robot_preset

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_the_example_files_are_the_papers_robot_and_cycle():
    """examples/paper_robot.toml and paper_cycle.toml give the preset's robot (6 kg) and cycle, every field."""
    loaded = rf.load_robot(EXAMPLES / "paper_robot.toml")
    assert rf.robot_to_dict(loaded.robot) == rf.robot_to_dict(robot_preset("default", payload=6.0))
    assert loaded.servo is None                                  # its [servo] table is commented out
    assert rf.cycle_to_dict(rf.load_cycle(EXAMPLES / "paper_cycle.toml")) == rf.cycle_to_dict(cycle_preset())


def test_the_other_example_robot_is_what_its_comment_says_and_reaches_its_move():
    """examples/other_robot.toml: the paper's robot with l1 0.26 m, l2 0.40 m, a 0.12 m and 2 kg,
    every other field the paper's; on the move its comment gives (300 mm at y 0.32 m) the rigid model
    closes at both ends (IGM then DGM to 1e-12 m), in the assembly mode of the pick point."""
    files = rf.setup("default", EXAMPLES / "other_robot.toml", pick=[-0.15, 0.32], place=[0.15, 0.32])
    paper = rf.robot_to_dict(robot_preset("default", payload=6.0))
    mine = rf.robot_to_dict(files.robot)
    changed = {k for k in paper if mine[k] != paper[k]}
    assert changed <= {"l1", "l2", "a", "payload", "assembly"} and {"l1", "l2", "a", "payload"} <= changed
    assert (mine["l1"], mine["l2"], mine["a"], mine["payload"]) == (0.26, 0.40, 0.12, 2.0)
    for point in (files.cycle.pick, files.cycle.place):
        np.testing.assert_allclose(np.asarray(dgm(files.robot, igm(files.robot, point))), point, atol=1e-12)


def test_a_robot_and_a_cycle_round_trip_through_toml(tmp_path):
    """Every field of another robot (other links, motors, payload, rotor, damping, working modes) and
    of another cycle survives writing and reading; the servo table too. The loaded robot's rigid
    model closes at the new pick point (IGM then DGM to 1e-12 m), with the new link lengths."""
    robot = robot_preset("default").replace(l1=0.26, l2=0.41, a=0.12, payload=2.5, rotor_inertia=0.02,
                                            damping=[0.0, 1e-5])
    cycle = rf.cycle_from_dict({"pick": [-0.14, 0.33], "place": [0.16, 0.33], "h": 0.03})
    (tmp_path / "r.toml").write_text(rf.robot_toml(robot, {"fc": 25.0, "rate": 4000.0, "feedforward": "rigid"}))
    (tmp_path / "c.toml").write_text(rf.cycle_toml(cycle))
    back = rf.load_robot(tmp_path / "r.toml")
    assert rf.robot_to_dict(back.robot) == rf.robot_to_dict(robot)
    assert back.servo == {"fc": 25.0, "rate": 4000.0, "feedforward": "rigid"}
    c2 = rf.load_cycle(tmp_path / "c.toml")
    assert rf.cycle_to_dict(c2) == rf.cycle_to_dict(cycle)
    q = igm(back.robot, c2.pick)
    np.testing.assert_allclose(np.asarray(dgm(back.robot, q)), [-0.14, 0.33], atol=1e-12)
    elbow = np.asarray(back.robot.bases[0]) + 0.26 * np.array([np.cos(q[0]), np.sin(q[0])])
    assert np.linalg.norm(np.array([-0.14, 0.33]) - elbow) == pytest.approx(0.41, abs=1e-12)


@pytest.mark.parametrize("text, match", [
    ("[robot]\nl3 = 0.2\nassembly = 1\n", r"unknown \[robot\] key\(s\) l3; allowed: l1, l2"),
    ("[robot]\nl1 = -0.2\nassembly = 1\n", r"l1 must be > 0"),
    ("[robot]\npayload = 1e9\nassembly = 1\n", r"static sag"),
    ("[robot]\nassembly = 1\n[servo]\nrate = 8000.0\n", r"\[servo\] table needs fc"),
    ("[robot]\nassembly = 1\n[servo]\nfc = 40.0\nkp = 3.0\n", r"unknown \[servo\] key\(s\) kp"),
    ("[robt]\n", r"unknown .*top-level key\(s\) robt"),
    ("[robot\n", r"not valid TOML"),
])
def test_a_bad_robot_file_is_refused_with_the_reason(tmp_path, text, match):
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(ValueError, match=match):
        rf.load_robot(tmp_path / "bad.toml")


def test_the_setup_takes_the_move_from_points_or_a_file_and_refuses_both():
    s = rf.setup("default", pick=(-0.15, 0.32), place=(0.15, 0.32), h=0.03)
    assert rf.cycle_to_dict(s.cycle) == {"pick": [-0.15, 0.32], "place": [0.15, 0.32], "h": 0.03, "lift": [0.0, 1.0]}
    assert s.name.startswith("default / pick (-0.15, 0.32)")
    with pytest.raises(ValueError, match="both the pick and the place"):
        rf.setup("default", pick=(-0.15, 0.32))
    with pytest.raises(ValueError, match="not both"):
        rf.setup("default", cycle_file=EXAMPLES / "paper_cycle.toml", pick=(0.0, 0.3), place=(0.1, 0.3))


def test_the_command_line_reads_payload_and_servo_from_the_robot_file_unless_a_flag_says_otherwise(tmp_path):
    """--payload and the servo flags win over the file's values, which win over the defaults (6 kg,
    8 kHz, a 0.01 kg m^2 rotor)."""
    robot = robot_preset("default").replace(payload=2.5, rotor_inertia=0.02)
    path = tmp_path / "r.toml"
    path.write_text(rf.robot_toml(robot, {"fc": 25.0, "rate": 4000.0, "feedforward": "flexible"}))
    parser = cli.build_parser()
    args = parser.parse_args(["sweep", "--robot", str(path)])
    setup = cli.run_setup(args)
    assert cli.file_payloads(args, setup, False) == 2.5
    assert cli.servo_options(args, setup) == {"fc": 25.0, "rate": 4000.0, "rotor_inertia": 0.02,
                                              "feedforward": "flexible"}
    args = parser.parse_args(["sweep", "--robot", str(path), "--payload", "1", "--servo", "40", "--servo-rate",
                              "8000", "--feedforward", "rigid", "--rotor-inertia", "0.01"])
    assert cli.file_payloads(args, cli.run_setup(args), False) == 1.0
    assert cli.servo_options(args, cli.run_setup(args)) == {"fc": 40.0, "rate": 8000.0, "rotor_inertia": 0.01,
                                                            "feedforward": "rigid"}
    args = parser.parse_args(["optimize"])
    assert cli.run_setup(args) == "default" and cli.file_payloads(args, "default", True) == [6.0]
    assert cli.servo_options(args, "default") is None


def test_an_unreachable_move_fails_before_anything_compiles(capsys):
    """A pick point out of the arms' reach: exit status 2 and a message naming the point and the arm."""
    status = cli.main(["sweep", "--pick", "-0.9", "0.0", "--place", "0.15", "0.3", "--repeats", "0"])
    assert status == 2
    assert "unreachable by arm 1" in capsys.readouterr().err


def test_a_robot_of_your_own_gets_no_paper_column():
    """The paper's natural frequencies belong to the paper's robot: ``modes`` puts them beside a
    preset's results only, never beside a robot from a file (the same payload, other links)."""
    from jaxflex.experiments import modes

    own = rf.setup("default", pick=(-0.15, 0.32), place=(0.15, 0.32))
    own = own._replace(robot=own.robot.replace(l1=0.26, l2=0.40))
    res = modes.compute(own, 6.0, points=2)
    assert res["paper"] is None
    rows = [line.split("|") for line in modes.text(res).splitlines() if line.startswith("| mode")]
    assert rows and all(r[3].strip() == "-" for r in rows)


def test_kinematics_of_a_robot_and_move_from_files():
    """``kinematics`` takes a robot and a move from files. The paper's robot and cycle as files
    (examples/) give the preset's Tables 5 and 6 to round-off: the same model reached another way.
    Other links on the same move leave the task accelerations as they are (the path and the law are
    Cartesian, the robot does not enter them) and change the joint accelerations (the inverse
    kinematics does: more than 1 % somewhere); and a robot of one's own gets no paper column."""
    from jaxflex.experiments import kinematics

    files = rf.setup("default", EXAMPLES / "paper_robot.toml", EXAMPLES / "paper_cycle.toml")
    preset, same = kinematics.compute("default", 0.43, 2000), kinematics.compute(files, 0.43, 2000)
    other = files._replace(robot=files.robot.replace(l1=0.26, l2=0.40))
    own = kinematics.compute(other, 0.43, 2000)
    flat = lambda res, key: np.asarray([[res[key][b][p] for p in sorted(res[key][b])] for b in sorted(res[key])])
    for key in ("task_acc_max", "joint_acc_max", "joint_acc_max_fd_1ms"):
        np.testing.assert_allclose(flat(same, key), flat(preset, key), rtol=1e-12)
    np.testing.assert_allclose(flat(own, "task_acc_max"), flat(preset, "task_acc_max"), rtol=1e-12)
    assert np.max(np.abs(flat(own, "joint_acc_max") / flat(preset, "joint_acc_max") - 1)) > 0.01
    assert "paper" in preset and "paper" not in same and "paper" not in own
    text = kinematics.tables_markdown(own)
    headers = [line for line in text.splitlines() if line.startswith(("| profile", "| curve"))]
    cells = {c.strip() for h in headers for c in h.split("|")}
    assert len(headers) == 3 and "diff" not in cells and not any("paper" in c for c in cells)
