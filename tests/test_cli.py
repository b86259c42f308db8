"""Every subcommand end to end through the console entry point (``jaxflex.experiments.cli:main``, what the
``jaxflex`` script calls), on small settings: exit code, the JSON keys and values, the files written.

The sweep and optimization commands and the quick reproduce run in one process (one ``xdist_group``,
with the optimizer's gradient checks in test_optimize.py) so that they share their compiled programs as they
do in one session: the nominal 6 kg model on the default 0.43 s grid, one design gradient for the
optimize, cycle-time, bench and reproduce runs, one law gradient, the richer model's programs.
An unexpected exception in a command fails its test: ``main`` turns it into one line on stderr and
exit status 1, and ``_run`` asserts status 0 and shows that line.
"""
import csv
import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from jax import monitoring

from jaxflex.experiments.cli import main
from jaxflex.metrics import METRICS

OPT = ["--payload", "6", "--tf", "0.43", "--steps", "2", "--train", "nominal"]
BOX = ["--box-samples", "4", "--richer-modes", "1"]        # a few random models, the cheapest richer model
COMMANDS = ("kinematics", "modes", "sweep", "optimize", "bench", "reproduce")


def _run(args, capsys, status=0):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert code == status, f"jaxflex {' '.join(map(str, args))} exited {code}: {err.strip()[-2000:]}"
    return out, err


def _finite_numbers(tree):
    if isinstance(tree, dict):
        for v in tree.values():
            yield from _finite_numbers(v)
    elif isinstance(tree, (list, tuple)):
        for v in tree:
            yield from _finite_numbers(v)
    elif isinstance(tree, float):
        yield tree


def test_console_script_runs_and_every_command_has_help(capsys):
    """The installed script starts (one process: each start imports jax, ~1 s), and every command's
    help comes from the function it calls (``main``)."""
    exe = shutil.which("jaxflex") or str(Path(sys.executable).parent / "jaxflex")
    proc = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "usage: jaxflex" in proc.stdout and all(c in proc.stdout for c in COMMANDS)
    for cmd in COMMANDS:
        with pytest.raises(SystemExit) as exit_:
            main([cmd, "--help"])
        assert exit_.value.code == 0
        assert capsys.readouterr().out.startswith(f"usage: jaxflex {cmd}")


def test_console_script_environment_adds_huge_pages_once(monkeypatch):
    """The console script re-runs itself with glibc's malloc on huge pages (``hugepages_env``):
    the tunable is appended to existing ones, never twice, and JAXFLEX_HUGEPAGES=0 turns it off."""
    from jaxflex.experiments import cli

    monkeypatch.setattr(cli.sys, "platform", "linux")
    monkeypatch.setattr("platform.libc_ver", lambda *a, **k: ("glibc", "2.36"))
    monkeypatch.setattr("builtins.open", lambda *a, **k: __import__("io").StringIO("always [madvise] never"))
    monkeypatch.delenv("JAXFLEX_HUGEPAGES", raising=False)
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.malloc.arena_max=2")
    env = cli.hugepages_env()
    assert env["GLIBC_TUNABLES"] == "glibc.malloc.arena_max=2:glibc.malloc.hugetlb=1"
    monkeypatch.setenv("GLIBC_TUNABLES", env["GLIBC_TUNABLES"])
    assert cli.hugepages_env() is None                        # already set: no second re-execution
    monkeypatch.delenv("GLIBC_TUNABLES")
    assert cli.hugepages_env()["GLIBC_TUNABLES"] == "glibc.malloc.hugetlb=1"
    monkeypatch.setenv("JAXFLEX_HUGEPAGES", "0")
    assert cli.hugepages_env() is None
    monkeypatch.delenv("JAXFLEX_HUGEPAGES")
    monkeypatch.setattr("builtins.open", lambda *a, **k: __import__("io").StringIO("always madvise [never]"))
    assert cli.hugepages_env() is None                        # huge pages off in the kernel


def test_optimize_command_defaults_are_the_study_defaults():
    """``jaxflex optimize`` without options runs ``StudyConfig()``: the CLI reads its defaults from the
    configuration (a module that imports no jax, so that --help starts at once)."""
    import dataclasses

    from jaxflex.experiments.cli import build_parser, study_config
    from jaxflex.optimize.config import ROBUST_POWER, StudyConfig

    a, c = build_parser().parse_args(["optimize"]), StudyConfig()
    o = c.train.optimizer
    assert (a.steps, a.lr, a.train, a.blend, a.box_points, a.box_samples, a.richer_modes) == (
        o.steps, o.learning_rate, c.training_set, c.train.blend, c.box_points, c.box_samples, c.richer_modes)
    assert a.coef is None           # the study's count, or an --init design's (study_config, below)
    assert (a.box_young, a.box_payload, tuple(a.box_damping), a.box_length, a.box_rotor) == dataclasses.astuple(c.box)
    assert a.objective == "worst" and c.absolute and c.train.power == ROBUST_POWER and a.free_path == c.free_path
    assert study_config(a) == c                                 # the configuration the command runs


@pytest.mark.xdist_group("commands")
def test_sweep_command(tmp_path, capsys):
    """The 12 combinations, 6 kg, tf 0.43 s, default step: the JSON keys of docs/conventions.md#file-formats,
    every metric of docs/conventions.md#metrics per run, finite and physically sized, and the table with
    every metric."""
    path = tmp_path / "w.json"
    out, _ = _run(["sweep", "--payload", "6", "--tf", "0.43", "--json", path], capsys)
    rec = json.loads(path.read_text())
    assert {"payload", "tf", "dt", "results", "timing"} <= set(rec)
    assert rec["payload"] == 6.0 and rec["tf"] == 0.43 and 0 < rec["dt"] <= 1e-4
    assert {"compile_s", "run_s"} <= set(rec["timing"])
    assert {(r["blend"], r["profile"]) for r in rec["results"]} == {
        (b, p) for b in ("lame", "clothoid", "polar") for p in ("poly7", "bang_bang", "trap_1_4", "trap_1_8")}
    for r in rec["results"]:
        assert set(METRICS) <= set(r)
        assert all(math.isfinite(r[m]) and r[m] > 0 for m in METRICS), r
        assert 40 < r["max_torque_nm"] < 400 and 1e-4 < r["dwell_residual_mm"] < 1.0, r
    assert "|e''(tf)| < 1 kHz" in out and "dwell" in out
    # every run carries its error estimate (docs/conventions.md#accuracy), within the tolerance
    acc = rec["accuracy"]
    assert acc["met"] and acc["ratio"] == 2.0 and acc["compared_with"]["coarse"] * 2 == rec["grid"]["coarse"]
    for r in rec["results"]:
        assert set(METRICS) <= set(r["error_estimate"])
        assert 0 < r["error_estimate"]["dwell_residual_mm"] <= r["dwell_residual_tolerance_mm"], r
        assert r["dwell_residual_tolerance_mm"] == max(0.005 * r["dwell_residual_mm"], 1e-6)
    assert " ± " in out and "tolerance 0.5 % of it or 1 nm: met" in out


@pytest.mark.xdist_group("servo-cli")       # its own programs, beside the command tests' worker
def test_sweep_command_under_a_servo(tmp_path, capsys):
    """``sweep --servo 40`` at 0.1 kg, 0.3 s: the 12 combinations under the servo, the servo's
    record (gains of the default rule, rate, rotor, feedforward, units) in the JSON and named in the
    text; every residual finite and positive, polar/poly7's 0.856 um (the fast model's, within 1 %:
    a gain or feedforward a few percent off moves it more; the fast model against the full one is
    test_servo_fast.py's), far below the perfect controller's 67 um (the servo damps the modes that
    involve the motors).

    Every run's error estimate, from the same sweep with every step halved (the step given, the
    default's 1e-4 s: no refinement), within the tolerance (docs/conventions.md#accuracy)."""
    path = tmp_path / "s.json"
    out, err = _run(["sweep", "--payload", "0.1", "--tf", "0.3", "--servo", "40", "--repeats", "0", "--dt", "1e-4",
                     "--json", path], capsys)
    rec = json.loads(path.read_text())
    sv = rec["servo"]
    assert sv["fc"] == 40.0 and sv["rate"] == 8000.0 and sv["rotor_inertia"] == 0.01 and sv["feedforward"] == "rigid"
    assert min(sv["kp"]) > 0 and min(sv["kd"]) > 0 and sv["units"]["kp"] == "N m/rad"
    assert len(rec["results"]) == 12
    for r in rec["results"]:
        assert all(math.isfinite(r[m]) and r[m] > 0 for m in METRICS), r
    polar = next(r for r in rec["results"] if (r["blend"], r["profile"]) == ("polar", "poly7"))
    assert polar["dwell_residual_mm"] * 1e3 == pytest.approx(0.856, rel=0.01)
    assert "servo fc 40 Hz" in out
    acc = rec["accuracy"]
    assert acc["ratio"] == 0.5 and acc["compared_with"]["coarse"] == 2 * rec["grid"]["coarse"] and acc["met"]
    assert acc["refinements"] == 0 and 0 < acc["max_estimate_over_tolerance"] <= 1
    worst = max(r["error_estimate"]["dwell_residual_mm"] / r["dwell_residual_tolerance_mm"] for r in rec["results"])
    assert worst == pytest.approx(acc["max_estimate_over_tolerance"], rel=1e-12)
    assert "misses the accuracy" not in err and "every step halved" in out and "it or 1 nm: met" in out


def _read_csv(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0], np.asarray(rows[1:], dtype=float)


@pytest.mark.xdist_group("commands")
def test_optimize_command_writes_its_outputs_and_resumes(tmp_path, capsys):
    """Two optimizer steps on the nominal model with --out: the study JSON, trajectory.csv (t, x, y,
    q1, q2, their rates and accelerations, the torque, at 10 kHz over [0, tf], from the pick to the
    place point, q the IGM of (x, y)) with controller.json, the
    figures and the checkpoint; a rerun resumes from the checkpoint and reports the same design."""
    from jaxflex.robot import cycle_preset, igm, robot_preset

    out_dir, j1, j2 = tmp_path / "opt", tmp_path / "o1.json", tmp_path / "o2.json"
    _run(["optimize", *OPT, *BOX, "--out", out_dir, "--json", j1], capsys)
    rec = json.loads(j1.read_text())
    for f in ("optimize.json", "trajectory.csv", "checkpoint.npz", "optimized_law.png", "error_series.png",
              "box_residuals.png"):
        assert (out_dir / f).is_file() and (out_dir / f).stat().st_size > 100, f
    assert json.loads((out_dir / "optimize.json").read_text())["laws"] == rec["laws"]
    assert rec["steps_run"] == 2 and len(rec["history"]) == 2 and rec["payloads"] == [6.0]
    assert rec["design"]["path"]["free"] is True and len(rec["design"]["path"]["corners"]) == 2
    assert rec["design"]["path"]["blend"] == "smoothstep" and rec["design"]["order"] == 3
    assert len(rec["model_sets"]["box"]) == 4 and rec["provenance"]["parameters"]["box"]["young"] == 0.05
    laws = rec["laws"]
    assert "optimized" in laws and any(k.endswith("(best paper)") for k in laws)
    assert any(k.endswith("+ZVD") for k in laws) and any(k.endswith("/ruckig") for k in laws)
    for v in laws.values():
        assert len(v["perturbed_mm"]) == 9 and len(v["damped_mm"]) == 1 and len(v["box_mm"]) == 4
        assert v["box_worst_mm"][0] == max(v["box_mm"]) >= v["box_p95_mm"][0] >= v["box_median_mm"][0] > 0
        assert len(v["richer_mm"]) == 1 and v["richer_mm"][0] > 0
        assert all(x > 0 and math.isfinite(x) for x in v["dwell_residual_mm"] + v["perturbed_mm"])
    assert all(math.isfinite(x) for x in _finite_numbers(rec))
    # every nominal result carries its error estimate (docs/conventions.md#accuracy): the best paper
    # combination's is the sweep's for that combination on the same grid (the same comparison), and
    # each law's tolerance is the larger of 0.5 % of its residual and 1 nm
    from jaxflex.sweep import Case, SweepConfig, run_sweep
    acc = rec["accuracy"]
    assert acc["ratio"] == 2.0 and acc["compared_with"]["coarse"] * 2 == rec["grid"]["coarse"]
    for v in laws.values():
        assert v["error_estimate_ratio"] in (2.0, 0.5) and v["error_estimate"]["dwell_residual_mm"][0] >= 0
        assert v["dwell_residual_tolerance_mm"][0] == pytest.approx(max(5e-3 * v["dwell_residual_mm"][0], 1e-6))
    best = next(k for k in laws if k.endswith("(best paper)"))
    res = run_sweep(robot_preset("default"), cycle_preset(), (Case(6.0, 0.43),), SweepConfig(dwell=0.1, timed=False))
    i, j = res.blends.index(rec["blend"]), res.profiles.index(rec["best_paper"])
    assert laws[best]["error_estimate"]["dwell_residual_mm"][0] == pytest.approx(
        float(res.accuracy.errors["dwell_residual_mm"][i, j, 0]), rel=1e-9)
    head, rows = _read_csv(out_dir / "trajectory.csv")
    assert head == ["t", "x", "y", "q1", "q2", "dq1", "dq2", "ddq1", "ddq2", "tau1", "tau2"]
    assert rows.shape == (4301, 11)
    np.testing.assert_allclose(np.diff(rows[:, 0]), 1e-4, rtol=1e-9)
    cycle, robot = cycle_preset(), robot_preset("default")
    np.testing.assert_allclose(rows[0, 1:3], cycle.pick, atol=1e-12)
    np.testing.assert_allclose(rows[-1, 1:3], cycle.place, atol=1e-12)
    for i in (0, 1234, 4300):
        np.testing.assert_allclose(rows[i, 3:5], np.asarray(igm(robot, rows[i, 1:3])), atol=1e-9)
    # the perfect controller's torque: at the pick at rest it holds the robot against gravity,
    # within the static sag's share of the rigid static torque; it moves the 6 kg payload in between
    controller = json.loads((out_dir / "controller.json").read_text())
    assert controller["feedforward"] == "flexible" and controller["kp"] is None and controller["csv_rate"] == 1e4
    assert controller["column_units"]["tau1"] == "N m" and controller["columns"] == head
    from jaxflex.rigid import rigid_torques
    static = np.asarray(rigid_torques(robot.replace(payload=6.0), rows[0, 3:5], np.zeros(2), np.zeros(2)))
    np.testing.assert_allclose(rows[0, 9:11], static, rtol=0.02, atol=0.02 * np.max(np.abs(static)))
    assert 20 < np.max(np.abs(rows[:, 9:11])) < 400
    # the rerun with the same directory resumes at step 2 and ends with the same design (the
    # checkpoint holds the optimizer's state only: the rerun skips the box and richer evaluations)
    _, err = _run(["optimize", *OPT, "--box-samples", "0", "--richer-modes", "0", "--out", out_dir,
                   "--json", j2], capsys)
    assert "resumed at step 2" in err
    rec2 = json.loads(j2.read_text())
    assert rec2["history"] == rec["history"] and rec2["design"] == rec["design"]
    assert rec2["laws"]["optimized"]["dwell_residual_mm"] == rec["laws"]["optimized"]["dwell_residual_mm"]
    # a new run from that design (--init) with no step: the same design, evaluated the same way
    j3 = tmp_path / "o3.json"
    _run(["optimize", *OPT[:-4], "--steps", "0", "--train", "nominal", "--init", j1, "--box-samples", "0",
          "--richer-modes", "0", "--json", j3], capsys)
    rec3 = json.loads(j3.read_text())
    assert rec3["steps_run"] == 0 and rec3["design"] == rec["design"]
    assert rec3["laws"]["optimized"]["dwell_residual_mm"] == rec["laws"]["optimized"]["dwell_residual_mm"]


@pytest.mark.xdist_group("commands")
def test_optimize_law_only_command(tmp_path, capsys):
    path = tmp_path / "law.json"
    _run(["optimize", *OPT, "--law-only", "--box-samples", "0", "--richer-modes", "0", "--json", path], capsys)
    rec = json.loads(path.read_text())
    assert rec["design"]["path"]["free"] is False and rec["steps_run"] == 2
    assert len(rec["design"]["coef"]) == 6
    assert "box_mm" not in rec["laws"]["optimized"] and "richer_mm" not in rec["laws"]["optimized"]
    assert all(math.isfinite(x) for x in _finite_numbers(rec))


@pytest.mark.xdist_group("commands")
def test_optimize_cycle_time_command(tmp_path, capsys):
    out_dir, path = tmp_path / "ct", tmp_path / "ct.json"
    _run(["optimize", "--cycle-time", "0.43", "0.40", "--payload", "6", "--tf", "0.43", "--steps", "2",
          "--train", "nominal", "--out", out_dir, "--json", path], capsys)
    rec = json.loads(path.read_text())
    assert [r["tf"] for r in rec["rows"]] == [0.43, 0.40]
    for r in rec["rows"]:
        assert r["paper_best_mm"] > 0 and r["optimized_mm"] > 0 and r["optimized_torque_nm"] > 0
    assert (out_dir / "cycle_time.json").is_file() and (out_dir / "cycle_time.png").stat().st_size > 1000


@pytest.mark.xdist_group("commands")
def test_bench_command(tmp_path, capsys):
    path = tmp_path / "b.json"
    out, _ = _run(["bench", "--quick", "--repeats", "1", "--json", path], capsys)
    rec = json.loads(path.read_text())
    sweep = rec["sweep"]
    assert sweep["rollouts"] == 24 and sweep["run_s"] > 0 and sweep["compile_s"] >= 0
    g = rec["gradient"]["design"]
    assert g["parameters"] == 12 and g["grad_run_s"] > 0 and g["grad_compile_s"] >= 0
    assert g["grad_temp_gib"] is None or g["grad_temp_gib"] > 0          # XLA temp of the gradient program
    from jaxflex.optimize.staged import PROGRAMS
    assert list(g["stages_s"]) == list(PROGRAMS) and all(t > 0 for t in g["stages_s"].values())
    assert "backward: first pass" in out                                # the per-program line is printed
    assert rec["peak_rss_mb"] > 0 and "rollout program" in out


def test_init_takes_the_design_of_a_record_and_refuses_another_blend_family_or_law_order(tmp_path):
    """``optimize --init FILE``: the design of an earlier run's JSON (both corners, the law), and a
    clear error, before anything compiles, when its blends or its law's order are not the run's."""
    from jaxflex.experiments.io import initial_design

    corners = [{"d_m": 0.021, "e_m": 0.03, "n": 3.2}, {"d_m": 0.024, "e_m": 0.035, "n": 3.4}]
    rec = {"design": {"path": {"blend": "smoothstep", "corners": corners, "free": True}, "law": "shaped",
                      "order": 3, "coef": [1.0, 1.1, 0.9, 1.0, 1.05, 0.97]}}
    path = tmp_path / "o.json"
    path.write_text(json.dumps(rec))
    x = initial_design(path, "smoothstep", 3)
    np.testing.assert_array_equal(np.asarray(x.d), [0.021, 0.024])
    np.testing.assert_array_equal(np.asarray(x.n), [3.2, 3.4])
    np.testing.assert_array_equal(np.asarray(x.coef), rec["design"]["coef"])
    with pytest.raises(ValueError, match="smoothstep blends, this run lame"):
        initial_design(path, "lame", 3)
    with pytest.raises(ValueError, match="order 3, this run 4"):
        initial_design(path, "smoothstep", 4)
    assert initial_design(path, None, 3).coef.shape == (6,)           # a law-only run takes the law alone
    # more coefficients: the same law written with 10 (Bernstein degree elevation), S and its first
    # three derivatives to 1e-12 of their scale; fewer than the design has: refused
    from jaxflex.profiles import profile_values, shaped

    x10 = initial_design(path, "smoothstep", 3, 10)
    assert x10.coef.shape == (10,) and initial_design(path, "smoothstep", 3, 6).coef.tolist() == rec["design"]["coef"]
    eta = np.linspace(0.0, 1.0, 201)
    for a, b in zip(profile_values(shaped(rec["design"]["coef"]), eta), profile_values(shaped(x10.coef), eta)):
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12 * float(np.max(np.abs(a))))
    with pytest.raises(ValueError, match="6 coefficients, which --coef 5 cannot hold"):
        initial_design(path, "smoothstep", 3, 5)
    # a servo run that refined its design: the refined design (not the perfect controller's), so that
    # a refinement continues where the last run ended; its law elevates the same way
    refined = {"corners": [{"d_m": 0.022, "e_m": 0.031, "n": 3.3}, {"d_m": 0.025, "e_m": 0.036, "n": 3.5}],
               "coef": [1.0, 1.2, 0.8, 1.0, 1.1, 0.9, 1.0, 1.02]}
    path.write_text(json.dumps({**rec, "closed_loop": {"refined": {"design": refined}}}))
    xr = initial_design(path, "smoothstep", 3)
    np.testing.assert_array_equal(np.asarray(xr.e), [0.031, 0.036])
    np.testing.assert_array_equal(np.asarray(xr.coef), refined["coef"])
    assert initial_design(path, "smoothstep", 3, 10).coef.shape == (10,)
    with pytest.raises(ValueError, match="8 coefficients, which --coef 6 cannot hold"):
        initial_design(path, "smoothstep", 3, 6)
    path.write_text(json.dumps({"laws": {}}))
    with pytest.raises(ValueError, match="not the JSON of a jaxflex optimize run"):
        initial_design(path, "smoothstep", 3)


def test_bench_servo_times_each_case_under_its_own_payloads_gains(monkeypatch, capsys):
    """``bench --servo FC``'s servo sweep (the sweeps themselves stubbed: they are the sweep command's
    and test_servo_fast.py's): one sweep per paper case, each under the default gains of its own
    payload (a 6 kg robot's gains on the 0.1 kg one could be unstable), times summed over the 24 runs."""
    from types import SimpleNamespace

    from jaxflex.experiments import bench
    from jaxflex.robot import cycle_preset, robot_preset
    from jaxflex.simulate import Grid

    seen = []

    def fake(robot, cycle, cases, config):
        seen.append((cases[0].payload, config.servo, config.estimate))
        return SimpleNamespace(tables_s=1.0, compile_s=2.0, run_s=0.25, grid=Grid())

    monkeypatch.setattr(bench, "run_sweep", fake)
    out = bench.servo_sweep_bench(robot_preset("default"), cycle_preset(), 40.0, repeats=1)
    assert [p for p, _, _ in seen] == [6.0, 0.1] and not any(e for _, _, e in seen)
    (_, heavy, _), (_, light, _) = seen
    assert heavy.fc == light.fc == 40.0 and np.all(np.asarray(heavy.kp) > 2 * np.asarray(light.kp))
    assert out["rollouts"] == 24 and out["run_s"] == 0.5 and out["per_rollout_ms"] == pytest.approx(500 / 24)


@pytest.mark.xdist_group("commands")
def test_reproduce_quick_command(tmp_path, capsys):
    """The main job's smoke run: every section, REPORT.md, its JSON/CSV and figures."""
    out_dir = tmp_path / "results"
    _run(["reproduce", "--quick", "--out", out_dir], capsys)
    report = (out_dir / "REPORT.md").read_text()
    for heading in ("## 1.", "## 2.", "## 3.", "optimiz"):
        assert heading in report, heading
    for f in ("kinematics_default.json", "modes_6kg.json", "vibration.json", "provenance.json",
              "optimize_6kg/study.json", "cycle_time/study.json", "figures/modes_along_path.png",
              "richer_model.json", "optimize_6kg/box_residuals.png"):
        assert (out_dir / f).is_file(), f
    assert "The paper's combinations on the richer model" in report and "box worst [mm]" in report
    rich = json.loads((out_dir / "richer_model.json").read_text())
    for model in ("paper model", "richer model"):
        cases = rich["dwell_residual_mm"][model]
        assert len(cases) == 2 and all(len(c) == 12 and all(v > 0 for v in c.values()) for c in cases.values())
    # the paper model's residuals are the vibration study's (the same sweep, not simulated twice)
    vib = json.loads((out_dir / "vibration.json").read_text())
    assert rich["dwell_residual_mm"]["paper model"]["6 kg, 0.43 s"]["clothoid/trap_1_8"] == \
        vib["case0"]["dwell_residual_mm"]["clothoid"]["trap_1_8"]
    assert not (out_dir / "optimize_0.1kg").exists()          # quick: the 6 kg case only
    assert not (out_dir / "closed_loop_6kg").exists()         # quick: no closed-loop section
    pngs = list((out_dir / "figures").glob("*.png"))
    assert len(pngs) >= 5 and all(p.stat().st_size > 1000 for p in pngs)
    assert not re.search(r"\bnan\b", report, flags=re.I)                 # no NaN in any table


def test_unexpected_errors_become_one_line_and_a_nonzero_status(monkeypatch, capsys):
    from jaxflex.experiments import sweep

    def broken(*a, **k):
        raise RuntimeError("something\nbroke")

    monkeypatch.setattr(sweep, "compute", broken)
    code = main(["sweep"])
    _, err = capsys.readouterr()
    assert code == 1
    assert err.strip() == ("jaxflex sweep: failed: RuntimeError: something broke (set JAXFLEX_TRACEBACK=1 "
                           "for the traceback)")


@pytest.fixture
def compilations():
    """Counts XLA compilations while the test runs."""
    count = [0]

    def listener(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            count[0] += 1

    monitoring.register_event_duration_secs_listener(listener)
    yield count
    monitoring.unregister_event_duration_listener(listener)


@pytest.mark.parametrize("args, named", [
    (["sweep", "--tf", "-1"], "tf"), (["sweep", "--tf", "nan"], "tf"), (["sweep", "--dwell", "0"], "dwell"),
    (["sweep", "--dt", "inf"], "dt"), (["sweep", "--payload", "-2"], "payload"),
    (["sweep", "--repeats", "-1"], "repeats"),
    (["optimize", "--tf", "-1"], "tf"), (["optimize", "--tf", "inf"], "tf"), (["optimize", "--steps", "-3"], "steps"),
    (["optimize", "--lr", "0"], "learning_rate"), (["optimize", "--lr", "nan"], "learning_rate"),
    (["optimize", "--servo", "40", "--servo-scenarios", "-1"], "scenarios"),
    (["optimize", "--servo", "40", "--servo-rounds", "0"], "rounds"),
    (["optimize", "--servo", "40", "--servo-power", "-8"], "power"),
    (["optimize", "--servo", "40", "--servo-lr", "nan"], "learning rate"),
    (["optimize", "--payload", "0"], "payloads"), (["optimize", "--payload", "nan"], "payloads"),
    (["optimize", "--coef", "0"], "n_coef"), (["optimize", "--cycle-time", "0.4", "-0.3"], "tfs"),
    (["optimize", "--cycle-time", "0.4", "--steps", "-1"], "steps"),
    (["optimize", "--init", "/nonexistent/optimize.json"], "--init"),
    (["bench", "--repeats", "0"], "repeats"), (["kinematics", "--steps", "0"], "steps"),
    (["modes", "--points", "1"], "points"), (["modes", "--payload", "inf"], "payload"),
])
def test_bad_input_is_rejected_before_anything_compiles(args, named, capsys, compilations):
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith(f"jaxflex {args[0]}: error: ") and named in err, err
    assert compilations[0] == 0, f"{compilations[0]} programs compiled before rejecting {args}"


@pytest.mark.slow      # the closed-loop programs' compiles (about 100 s); the default suite keeps sweep --servo's
def test_optimize_command_under_a_servo(tmp_path, capsys):
    """``optimize --servo 40`` (two perfect-controller steps, no refinement, the nominal model only):
    the closed-loop record with the 12 paper combinations under the servo, every trajectory's row,
    the best paper combination's the least of the 12, and the export for that servo (its gains, the
    flexible feedforward)."""
    out_dir, j2 = tmp_path / "opt", tmp_path / "o2.json"
    out, _ = _run(["optimize", *OPT, "--box-samples", "0", "--richer-modes", "0", "--out", out_dir,
                   "--json", j2, "--servo", "40", "--servo-steps", "0", "--servo-samples", "0",
                   "--no-servo-corners", "--servo-fcs"], capsys)
    rec2 = json.loads(j2.read_text())
    closed = rec2["closed_loop"]
    assert list(closed["fcs"]) == ["40"] and closed["controller"]["feedforward"] == "flexible"
    assert len(closed["paper"]["40"]["dwell_residual_um"]) == 12
    rows = closed["fcs"]["40"]
    assert {"optimized", "lame/poly7"} <= set(rows) and any(k.endswith("(best paper)") for k in rows)
    for v in rows.values():
        assert v["nominal_um"] > 0 and v["perfect_um"] > 0 and v["unstable"] == 0 and v["box_models"] == 1
    best = min(closed["paper"]["40"]["dwell_residual_um"].values())
    assert next(v for k, v in rows.items() if k.endswith("(best paper)"))["nominal_um"] == pytest.approx(best, rel=1e-9)
    assert "Under the servo" in out and "fc 40 Hz" in out
    controller = json.loads((out_dir / "controller.json").read_text())
    assert controller["controller"] == "servo" and controller["fc"] == 40.0 and controller["rate"] == 8000.0
    assert controller["feedforward"] == "flexible" and min(controller["kp"]) > 0 and min(controller["kd"]) > 0


def test_a_given_step_that_undersamples_the_dwell_is_warned_before_anything_compiles(monkeypatch, capsys):
    """``sweep --dt 1``: the dwell sampled every 0.1 s can miss the first mode's peak entirely, and the
    motion runs in frozen intervals of about 2.24 ms, not 1 s: both said on stderr before any table is
    built (the tables' builder stopped here), at each payload. The bound is the sampled cosine's:
    at dt 1 ms and 0.1 kg (129 Hz) 1 - cos(pi f1 h) = 8.1 %, and at the default step nothing."""
    from jaxflex import sweep as sw
    from jaxflex.frequencies import modes_at_point
    from jaxflex.robot import cycle_preset, robot_preset

    class Stop(Exception):
        pass

    def stop(*a, **k):
        raise Stop

    monkeypatch.setattr(sw, "_stacked_tables", stop)
    assert main(["sweep", "--payload", "0.1", "--tf", "0.3", "--dt", "1"]) != 0       # stopped at the tables
    err = capsys.readouterr().err
    assert "failed: Stop" in err, err
    assert "jaxflex sweep: warning: dt 1 s samples the dwell every 0.1 s" in err and "missed entirely" in err
    assert "steps of 0.00" in err and "frozen-coefficient intervals" in err
    robot, cycle = robot_preset("default"), cycle_preset()
    cases = [sw.Case(0.1, 0.3)]
    f1 = float(modes_at_point(robot.replace(payload=0.1), np.asarray(cycle.place))[0])
    said = sw.step_warnings(robot, cycle, cases, 0.1, 1e-3, sw.default_grid(robot, [0.3], 0.1, 1e-3))
    assert 100 < f1 < 160 and len(said) == 1, (f1, said)
    assert f"up to {100 * (1 - math.cos(math.pi * f1 * 1e-3)):.3g} %" in said[0], said
    assert sw.step_warnings(robot, cycle, cases, 0.1, 1e-4, sw.default_grid(robot, [0.3], 0.1, 1e-4)) == []
