"""The controller-ready export (``jaxflex.export``): ``trajectory.csv`` and ``controller.json``.

The columns are checked against physics, not against the code that wrote them: the motor angles
against the inverse kinematics of the desired position, the rates and accelerations against finite
differences of the angles, the rigid feedforward against the power balance of the rigid robot (its
kinetic and potential energy computed here from the bodies' motion), the flexible feedforward
against the rigid one (the elastic links change the torque by a small part) and the gains against
the bandwidth rule computed from the rigid inertia at the path's midpoint.
"""
import csv
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import export
from jaxflex import servo as sv
from jaxflex.path import make_path, path_frame
from jaxflex.profiles import make_profile
from jaxflex.rigid import _bodies
from jaxflex.robot import cycle_preset, igm, robot_preset

CYCLE = cycle_preset()
PATH = make_path(CYCLE, "lame", 0.025)
TF = 0.43


def _read(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0], np.asarray(rows[1:], dtype=float)


def _rigid_energy(robot, q, qd):
    """Kinetic + gravity potential energy [J] of the rigid robot (rods, payload point, rotors) at
    (q, q'), from the bodies' positions and velocities (forward-mode derivative of the DGM)."""
    (com, ang, x), (v, w, vx) = jax.jvp(lambda a: _bodies(robot, a), (q,), (qd,))
    m1, m2 = robot.rho * robot.area * robot.l1, robot.rho * robot.area * robot.l2
    m = jnp.stack([m1, m2, m1, m2])
    inertia = m * jnp.stack([robot.l1, robot.l2, robot.l1, robot.l2]) ** 2 / 12.0
    kinetic = 0.5 * (jnp.sum(m * jnp.sum(v**2, 1)) + jnp.sum(inertia * w**2) + robot.payload * vx @ vx
                     + robot.rotor_inertia * qd @ qd)
    potential = -jnp.sum(m * (com @ robot.gravity)) - robot.payload * x @ robot.gravity
    return kinetic + potential


@pytest.fixture(scope="module")
def rigid_files(tmp_path_factory):
    robot = robot_preset("default", payload=6.0)
    servo = sv.cycle_servo(robot, CYCLE, 40.0, feedforward="rigid")
    out = tmp_path_factory.mktemp("export")
    csv_path, js = export.write_controller_files(out, robot, PATH, make_profile("poly7"), TF, servo, rate=8000)
    return robot, servo, csv_path, js


def test_the_columns_are_the_motion_its_derivatives_and_the_rigid_feedforward(rigid_files):
    """Header and rows at 8 kHz over [0, tf]; q the IGM of (x, y) to 1e-9 rad; dq and ddq the
    central differences of q and dq to 1e-3 and 1e-2 of their peaks (the differences' O(h^2)
    error at h = 125 us, O(h) for ddq where the jerk jumps at the blends' G2 joins); tau . dq the rate of change of the rigid energy (rotor included) to 1e-3 of the
    peak power (a force or mass a few percent off misses it by percents)."""
    robot, servo, csv_path, _ = rigid_files
    header, rows = _read(csv_path)
    assert header == list(export.COLUMNS)
    col = {name: rows[:, i] for i, name in enumerate(header)}
    assert rows.shape[0] == round(TF * 8000) + 1 and col["t"][0] == 0.0 and abs(col["t"][-1] - TF) < 1e-12
    q = np.stack([col["q1"], col["q2"]], 1)
    q_igm = np.asarray(jax.vmap(lambda x: igm(robot, x))(jnp.asarray(np.stack([col["x"], col["y"]], 1))))
    assert np.max(np.abs(q - q_igm)) < 1e-9
    h = 1 / 8000
    dq, ddq = np.stack([col["dq1"], col["dq2"]], 1), np.stack([col["ddq1"], col["ddq2"]], 1)
    fd = (q[2:] - q[:-2]) / (2 * h)
    assert np.max(np.abs(fd - dq[1:-1])) < 1e-3 * np.max(np.abs(dq))
    fdd = (dq[2:] - dq[:-2]) / (2 * h)
    assert np.max(np.abs(fdd - ddq[1:-1])) < 1e-2 * np.max(np.abs(ddq))   # q''' jumps at the blends' joins
    assert np.max(np.abs(dq[[0, -1]])) < 1e-9 * np.max(np.abs(dq))       # at rest at both ends
    r = sv.with_rotor(robot, servo)
    energy = np.asarray(jax.jit(jax.vmap(lambda a, b: _rigid_energy(r, a, b)))(jnp.asarray(q), jnp.asarray(dq)))
    tau = np.stack([col["tau1"], col["tau2"]], 1)
    power = np.sum(tau * dq, 1)
    de = (energy[2:] - energy[:-2]) / (2 * h)
    assert np.max(np.abs(de - power[1:-1])) < 1e-3 * np.max(np.abs(power))
    # the row at tf: the torque the servo holds through the dwell, the gravity torque dV/dq at the place
    grav = np.asarray(jax.grad(lambda a: _rigid_energy(r, a, jnp.zeros(2)))(jnp.asarray(q[-1])))
    np.testing.assert_allclose(tau[-1], grav, rtol=1e-9, atol=1e-9 * np.max(np.abs(tau)))


def test_the_controller_file_states_the_bandwidth_gains_and_every_unit(rigid_files):
    """kp = J (2 pi fc)^2 and kd = 2 0.7 J 2 pi fc with J the mean diagonal of the rigid inertia
    (rotor included) at the path's arc-length midpoint, computed here from the kinetic energy's
    Hessian; the rate, rotor, kind, fc, and a unit for every CSV column."""
    robot, servo, _, js = rigid_files
    rec = json.loads(js.read_text())
    r = sv.with_rotor(robot, servo)
    qa = igm(r, path_frame(PATH, 0.5 * PATH.length).pos)
    mass = jax.hessian(lambda v: _rigid_energy(r, qa, v) - _rigid_energy(r, qa, jnp.zeros(2)))(jnp.zeros(2))
    j = float(np.mean(np.diag(mass)))
    w = 2 * np.pi * 40.0
    assert np.allclose(rec["kp"], j * w**2, rtol=1e-9) and np.allclose(rec["kd"], 2 * 0.7 * j * w, rtol=1e-9)
    assert rec["rate"] == 8000 and rec["rotor_inertia"] == 0.01 and rec["feedforward"] == "rigid"
    assert rec["fc"] == 40.0 and rec["csv_rate"] == 8000 and rec["columns"] == list(export.COLUMNS)
    assert set(rec["column_units"]) == set(export.COLUMNS) and rec["units"]["kp"] == "N m/rad"


@pytest.mark.xdist_group("commands")        # the 6 kg, 0.43 s programs of the command tests
def test_the_flexible_feedforward_differs_from_the_rigid_one_by_the_elastic_part(tmp_path):
    """The flexible feedforward (the perfect controller's torque of the elastic model) against the
    rigid one on the same motion at 1 kHz: within 30 % of the peak torque (measured: 20 %, the
    links' deflection under the inertial loads) but not equal (above 1 %); at t = 0 both hold the
    pick pose against gravity (to 2 % of the peak: the static sag)."""
    robot = sv.with_rotor(robot_preset("default", payload=6.0), sv.cycle_servo(robot_preset("default", payload=6.0),
                                                                             CYCLE, 15.0))
    law = make_profile("poly7")
    rigid = export.trajectory_table(robot, PATH, law, TF, 1000, "rigid")
    flexible = export.trajectory_table(robot, PATH, law, TF, 1000, "flexible")
    assert np.array_equal(rigid[:, :9], flexible[:, :9])
    diff, peak = np.abs(rigid[:, 9:] - flexible[:, 9:]), np.max(np.abs(rigid[:, 9:]))
    assert 1e-2 * peak < np.max(diff) < 0.3 * peak
    assert np.max(diff[0]) < 0.02 * peak
    # a servo holds the file's last row after the motion: with ``hold_rest`` (what a servo export
    # writes) that row is the elastic model's rest torque at the place, the rigid gravity torque to
    # 1e-3 of the peak (measured 2.4e-5: the sag term), not the motion's left limit, which carries
    # the reaction of the links' vibration at tf (measured 8.9e-2 of the peak off it, which held
    # would move the servo's rest pose by millimetres); every other row is unchanged
    held = export.trajectory_table(robot, PATH, law, TF, 1000, "flexible", hold_rest=True)
    assert np.array_equal(held[:-1], flexible[:-1]) and np.array_equal(held[-1, :9], flexible[-1, :9])
    rest = rigid[-1, 9:]                                    # q' = q'' = 0 at tf: the gravity torque
    assert np.max(np.abs(held[-1, 9:] - rest)) < 1e-3 * peak
    assert np.max(np.abs(flexible[-1, 9:] - rest)) > 1e-2 * peak
    # and the files a servo's export writes carry that row
    six = robot_preset("default", payload=6.0)
    servo = sv.cycle_servo(six, CYCLE, 15.0, feedforward="flexible")
    csv_path, _ = export.write_controller_files(tmp_path, six, PATH, law, TF, servo, rate=1000)
    _, rows = _read(csv_path)
    np.testing.assert_allclose(rows[-1, 9:], held[-1, 9:], rtol=1e-10)


def test_the_export_refuses_a_bad_rate():
    with pytest.raises(ValueError, match="rate"):
        export.sample_times(0.43, 0.0)
