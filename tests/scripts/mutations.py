"""Mutation check of the test suite: does it fail when the physics is wrong?

Each mutation puts one modelling error into a copy of the code (a force, mass, stiffness, damping or
gravity term 5 % off, a linearization coefficient or a rollout term 5 % off, a metric computed
wrongly), runs the given tests with ``-x`` and records whether they failed (the mutation was caught)
and which test caught it. The copy is restored after every mutation.

Usage (from a scratch clone with its own editable install, never the working tree):

    python tests/scripts/mutations.py --root /tmp/mutwork --python /tmp/mutvenv/bin/python \
        [--only ID ...] [--tests tests/test_a.py ...] [--json out.json]

Not part of the test suite (it runs the suite once per mutation).
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

F = "* 1.05"
GRADIENT_TEST = "tests/test_optimize.py::test_the_optimizers_own_gradient_matches_central_differences"
# (id, file, exact text, replacement, what is wrong[, tests to run first])
MUTATIONS = [
    # ---- the model (paper Section 2)
    ("m1_proximal_mass", "jaxflex/model.py", "return robot.rho * robot.area * robot.l1, robot.rho",
     "return 1.05 * robot.rho * robot.area * robot.l1, robot.rho", "proximal link mass +5 %"),
    ("m2_distal_mass", "jaxflex/model.py", "robot.rho * robot.area * robot.l2\n",
     "1.05 * robot.rho * robot.area * robot.l2\n", "distal link mass +5 %"),
    ("m3_payload_inertia", "jaxflex/model.py", "jnp.broadcast_to(robot.payload, (2,))]))",
     "jnp.broadcast_to(1.05 * robot.payload, (2,))]))", "payload inertia +5 % (not its weight)"),
    ("m4_payload_weight", "jaxflex/model.py", "robot.payload * g @ x)", "1.05 * robot.payload * g @ x)",
     "payload weight +5 %"),
    ("m5_link_weight", "jaxflex/model.py", "grav = -(m1 * g @ (c1 + c3)", "grav = -(1.05 * m1 * g @ (c1 + c3)",
     "proximal links' weight +5 %"),
    ("m6_bending_stiffness", "jaxflex/model.py", "kb = robot.young * robot.second_moment",
     "kb = 1.05 * robot.young * robot.second_moment", "bending stiffness +5 %"),
    ("m7_axial_stiffness", "jaxflex/model.py", "ka = robot.young * robot.area", "ka = 1.05 * robot.young * robot.area",
     "axial stiffness +5 %"),
    ("m8_rotation_inertia", "jaxflex/model.py", "m_tt = m * (l * l / 3.0 + qe @ mphi @ qe)",
     "m_tt = m * (1.05 * l * l / 3.0 + qe @ mphi @ qe)", "proximal link rotary inertia +5 %"),
    ("m9_rotation_elastic_coupling", "jaxflex/model.py", "m_tq = m * l * jnp.asarray(modes.xi_phi_int)",
     "m_tq = 1.05 * m * l * jnp.asarray(modes.xi_phi_int)", "rotation-bending inertial coupling +5 %"),
    ("m10_modal_mass", "jaxflex/model.py", "bot = jnp.concatenate([m_aq.T, m_tq[:, None], m * mphi], axis=1)",
     "bot = jnp.concatenate([m_aq.T, m_tq[:, None], 1.05 * m * mphi], axis=1)", "bending modal mass +5 %"),
    ("m11_centrifugal", "jaxflex/model.py", "h = mdot_qd - dtdq", "h = mdot_qd - 1.05 * dtdq",
     "Coriolis/centrifugal term dT/dq +5 %"),
    ("m11b_centrifugal_residual", "jaxflex/model.py", "gen = mq @ qdd + mdot_qd - dtdq",
     "gen = mq @ qdd + mdot_qd - 1.05 * dtdq", "dT/dq +5 % in the matrix-free residual (the fast model's)"),
    ("m11c_mass_rate", "jaxflex/model.py", "return mq, tangent(qd) @ qd, dtdq",
     "return mq, 1.05 * tangent(qd) @ qd, dtdq", "M' q' +5 % (both the full and the fast model)"),
    ("m12_constraint_acceleration", "jaxflex/model.py", "gen = mq @ w_acc + h", "gen = mq @ (1.05 * w_acc) + h",
     "constraint acceleration term +5 %"),
    ("m13_damping", "jaxflex/model.py", "(alpha * jnp.asarray(mm) + beta * k) @ _part(qd, idx)",
     "(alpha * jnp.asarray(mm) + 1.05 * beta * k) @ _part(qd, idx)", "stiffness-proportional damping +5 %"),
    ("m14_rotor_inertia", "jaxflex/model.py", "jnp.broadcast_to(robot.rotor_inertia, (2,))",
     "jnp.broadcast_to(1.05 * robot.rotor_inertia, (2,))", "rotor inertia +5 %"),
    ("m15_axial_beam_mass_offset", "jaxflex/model.py", "m_at = m * r @ jnp.stack([0.0, 0.5 * l + phi @ qe])",
     "m_at = m * r @ jnp.stack([0.0, 0.525 * l + phi @ qe])", "distal link centre of mass 5 % off"),
    ("m16_tip_deflection", "jaxflex/model.py", "tips = (bend.tip, ax.tip, bend.tip, ax.tip)",
     "tips = (1.05 * bend.tip, ax.tip, 1.05 * bend.tip, ax.tip)", "proximal tip deflection in the loop closure +5 %"),
    ("m17_one_arm_mass", "jaxflex/model.py", "(dist(b22[2], e22, p22), np.r_[lay.base22",
     "(1.05 * dist(b22[2], e22, p22), np.r_[lay.base22", "one distal link 5 % heavier than the other"),
    ("b1_bending_integral", "jaxflex/beams.py", "stiffness=(dphi * w[:, None]).T @ dphi,",
     "stiffness=1.05 * (dphi * w[:, None]).T @ dphi,", "modal stiffness integrals +5 %"),
    ("b2_mass_integral", "jaxflex/beams.py", "mass=(phi * w[:, None]).T @ phi,",
     "mass=1.05 * (phi * w[:, None]).T @ phi,", "modal mass integrals +5 %"),
    # ---- the linearization (tables)
    ("l1_forcing_acc", "jaxflex/linearized.py", "f1=-r1[e]", "f1=-1.05 * r1[e]",
     "forcing per unit s'' +5 %"),
    ("l2_forcing_vel", "jaxflex/linearized.py", "f2=-r2[e]", "f2=-1.05 * r2[e]",
     "forcing per unit s'^2 +5 %"),
    ("l3_gravity_forcing", "jaxflex/linearized.py", "f0=-r0[e]", "f0=-1.05 * r0[e]", "gravity forcing +5 %"),
    ("l4_stiffness", "jaxflex/linearized.py", "k0=j0[e]", "k0=1.05 * j0[e]", "stiffness K0 +5 %"),
    ("l5_mass", "jaxflex/linearized.py", "mass=m[e, e]", "mass=1.05 * m[e, e]", "elastic mass +5 %"),
    ("l6_torque_coupling", "jaxflex/linearized.py", "m_ae=m[a, e]", "m_ae=1.05 * m[a, e]",
     "torque coupling of q_e'' +5 %"),
    ("l7_rigid_torque", "jaxflex/linearized.py", "t1=r1[a]", "t1=1.05 * r1[a]",
     "rigid inertial torque +5 %"),
    ("l8_torque_stiffness", "jaxflex/linearized.py", "tq0=j0[a]", "tq0=1.05 * j0[a]",
     "torque from q_e +5 %"),
    ("l9_gyroscopic", "jaxflex/linearized.py", "c1=jv[e]", "c1=1.05 * jv[e]",
     "gyroscopic coupling +5 %"),
    ("l10_centrifugal_stiffness", "jaxflex/linearized.py", "k2=j2[e]", "k2=1.05 * j2[e]",
     "centrifugal stiffness +5 %"),
    ("l11_output_map", "jaxflex/linearized.py", "jx=jx, jx1=jx1", "jx=1.05 * jx, jx1=jx1",
     "end-effector map J +5 %"),
    ("l13_damping_matrix", "jaxflex/linearized.py", "c0=mdl.damping_matrix(robot)",
     "c0=1.05 * mdl.damping_matrix(robot)", "damping C0 in the tables +5 %"),
    ("l14_motion_term", "jaxflex/model.py", "mq @ qdd + mdot_qd - dtdq, project)",
     "mq @ qdd + mdot_qd - 1.05 * dtdq, project)", "dT/dq +5 % in the residual's motion term (the tables')"),
    ("l15_inertia_term", "jaxflex/model.py", "mass_matrix(robot, q) @ _assemble(lay, qadd",
     "1.05 * mass_matrix(robot, q) @ _assemble(lay, qadd", "M(q) q'' +5 % in the residual's inertia term"),
    ("l16_interpolation_tangent", "jaxflex/linearized.py", "tangent = tangent + jnp.tensordot(w, dv[idx], axes=1)",
     "tangent = tangent + 1.05 * jnp.tensordot(w, dv[idx], axes=1)",
     "the tables' interpolation tangent in the table values (reverse mode) +5 %", [GRADIENT_TEST]),
    ("l17_interpolation_slope", "jaxflex/linearized.py",
     "tangent = tangent + dt * jnp.tensordot(w_t, window, axes=1)",
     "tangent = tangent + 1.05 * dt * jnp.tensordot(w_t, window, axes=1)",
     "the interpolant's slope in arc length (reverse mode) +5 %", [GRADIENT_TEST]),
    ("l12_remainder", "jaxflex/linearized.py", "return (r1 - r0) - (8.0", "return 1.05 * (r1 - r0) - 1.05 * (8.0",
     "second-order remainder +5 %"),
    # ---- the rollout
    ("s1_forcing", "jaxflex/linearized.py", "return self.f0 + self.f2 * ds**2 + self.f1 * dds,",
     "return self.f0 + self.f2 * ds**2 + 1.05 * self.f1 * dds,", "inertial forcing in the rollout +5 %"),
    ("s2_stiffness", "jaxflex/linearized.py", "return self.k0 + self.k2 * ds**2", "return 1.05 * self.k0 + self.k2 * ds**2",
     "stiffness in the rollout +5 %"),
    ("s3_torque_coupling", "jaxflex/simulate.py", "tau = tr + mv(fz.tq, q) + mv(fz.tv, qd) + mv(fz.m_ae, qdd)",
     "tau = tr + mv(fz.tq, q) + mv(fz.tv, qd) + 1.05 * mv(fz.m_ae, qdd)", "torque coupling in the outputs +5 %"),
    ("s4_acceleration_output", "jaxflex/simulate.py", "edd = (node(c.jx, qdd) + 2.0 * ds",
     "edd = (1.05 * node(c.jx, qdd) + 2.0 * ds", "end-effector acceleration +5 %"),
    ("s5_propagator_forcing", "jaxflex/simulate.py", "return t_mat @ phi_y @ t_inv, t_mat @ g0_y @ li,",
     "return t_mat @ phi_y @ t_inv, 1.05 * t_mat @ g0_y @ li,", "forcing response of the propagator +5 %"),
    ("s6_initial_state", "jaxflex/simulate.py", 'q0 = linalg.solve(rest0.k0, rest0.f0)',
     'q0 = 1.05 * linalg.solve(rest0.k0, rest0.f0)', "initial static deflection +5 %"),
    ("s7_energy", "jaxflex/simulate.py", "+ 0.5 * dq @ ksym @ dq", "+ 0.525 * dq @ ksym @ dq",
     "elastic part of the residual energy +5 %"),
    ("s8_static_reference", "jaxflex/simulate.py", 'e_static = rest.jx @ q_star', 'e_static = 1.05 * rest.jx @ q_star',
     "dwell reference sag +5 %"),
    ("s9_rigid_torque", "jaxflex/linearized.py", "self.t0 + self.t2 * ds**2 + self.t1 * dds",
     "self.t0 + self.t2 * ds**2 + 1.05 * self.t1 * dds", "rigid torque in the rollout +5 %"),
    ("s10_damping", "jaxflex/linearized.py", "self.c0 + self.c1 * ds", "1.05 * self.c0 + self.c1 * ds",
     "damping in the rollout +5 %"),
    # ---- the metrics
    ("x1_rms", "jaxflex/metrics.py", '"rms_acc_error": jnp.sqrt(jnp.mean(', '"rms_acc_error": 1.05 * jnp.sqrt(jnp.mean(',
     "rms_acc_error +5 %"),
    ("x2_dwell_static", "jaxflex/metrics.py", "jnp.max(_norm(series.e_dwell - series.e_static[None]))",
     "jnp.max(_norm(series.e_dwell - 0.95 * series.e_static[None]))", "dwell residual with 95 % of the sag removed"),
    ("x3_residual_pos", "jaxflex/metrics.py", '"residual_pos_mm": 1e3 * _norm(series.e_dwell[0])',
     '"residual_pos_mm": 1e3 * _norm(series.e_dwell[1])', "residual position one sample late"),
    ("x4_torque", "jaxflex/metrics.py", '"max_torque_nm": jnp.max(jnp.abs(series.tau))',
     '"max_torque_nm": jnp.max(series.tau)', "max torque ignores negative torques"),
    ("x5_energy", "jaxflex/metrics.py", '"residual_energy": series.energy_tf', '"residual_energy": 1.05 * series.energy_tf',
     "residual energy +5 %"),
    ("x6_deflection", "jaxflex/metrics.py", '"max_deflection_mm": 1e3 * jnp.max(_norm(series.e))',
     '"max_deflection_mm": 1e3 * jnp.max(_norm(series.e[:-1]))', "max deflection misses the last sample"),
    # ---- the optimizer's gradient (optimize/staged.py)
    # (a sixth element: the tests that check this code, run first, before the physics files)
    ("o1_staged_residual_row", "optimize/staged.py", "total = total + d_residual[i] * g_residual",
     "total = total + 1.05 * d_residual[i] * g_residual", "each model's residual row of the gradient +5 %",
     [GRADIENT_TEST]),
    ("o2_staged_torque_row", "optimize/staged.py", "total = total + d_torque[i] * g_torque",
     "total = total + 1.05 * d_torque[i] * g_torque", "the torque penalty's row of the gradient +5 %",
     [GRADIENT_TEST]),
    # ---- the workspace tables the design gradient interpolates (jaxflex/workspace.py)
    ("w1_workspace_speed_term", "jaxflex/workspace.py", "jnp.stack([e[0], e[2] - e[0] - e[1], e[1], e[3], e[4]])",
     "jnp.stack([e[0], e[2] - e[0] - e[1], 1.05 * e[1], e[3], e[4]])",
     "the workspace's b^2 coefficient (s'^2 terms of the second motor) +5 %", ["tests/test_workspace.py"]),
]

DEFAULT_TESTS = ["tests/test_rollout_physics.py::test_metrics_on_a_series_with_known_answers",
                 "tests/test_model_energy.py", "tests/test_linearization.py", "tests/test_model.py",
                 "tests/test_rollout_physics.py", "tests/test_simulate.py"]


def run_one(root: Path, python: str, mutation, tests, timeout: float) -> dict:
    mid, rel, old, new, what = mutation[:5]
    tests = [*mutation[5:6][0], *tests] if len(mutation) > 5 else tests
    path = root / rel
    text = path.read_text()
    count = text.count(old)
    if count != 1:
        return {"id": mid, "what": what, "status": f"not applied ({count} matches)"}
    path.write_text(text.replace(old, new))
    started = time.time()
    try:
        proc = subprocess.run([python, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-m", "not slow",
                               *tests], cwd=root, capture_output=True, text=True, timeout=timeout)
        out = proc.stdout + proc.stderr
        failed = re.findall(r"^FAILED (\S+)", out, flags=re.M) or re.findall(r"^ERROR (\S+)", out, flags=re.M)
        status = "caught" if proc.returncode != 0 else "MISSED"
        return {"id": mid, "what": what, "status": status, "by": failed[:1], "seconds": round(time.time() - started)}
    except subprocess.TimeoutExpired:
        return {"id": mid, "what": what, "status": "timeout", "seconds": round(time.time() - started)}
    finally:
        path.write_text(text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True, help="a scratch clone with its own editable install")
    ap.add_argument("--python", default=sys.executable, help="the clone's Python (its venv)")
    ap.add_argument("--only", nargs="*", help="mutation ids to run (default: all)")
    ap.add_argument("--tests", nargs="*", default=DEFAULT_TESTS, help="test files or ids to run per mutation")
    ap.add_argument("--timeout", type=float, default=1800.0)
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    root = Path(args.root).resolve()
    if (root / ".git").exists() and subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True,
                                                   text=True).stdout.strip() and not args.only:
        print("note: the clone has uncommitted changes (they are kept; each mutation is reverted)", file=sys.stderr)
    results = []
    for m in MUTATIONS:
        if args.only and m[0] not in args.only:
            continue
        r = run_one(root, args.python, m, args.tests, args.timeout)
        results.append(r)
        print(f"{r['id']:32s} {r['status']:8s} {' '.join(r.get('by', []))} ({r.get('seconds', 0)} s) - {r['what']}",
              flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(results, indent=1))
    missed = [r["id"] for r in results if r["status"] != "caught"]
    print(f"{len(results) - len(missed)}/{len(results)} caught" + (f"; not caught: {missed}" if missed else ""))
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
