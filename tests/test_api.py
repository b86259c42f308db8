"""The public API: ``import jaxflex as jf`` reaches every name a researcher uses, without importing
JAX until one is used (so that the command line's --help and a notebook's first cell start at once)."""
import subprocess
import sys


def test_every_public_name_resolves():
    import jaxflex as jf

    missing = []
    for name in jf.__all__:
        try:
            getattr(jf, name)
        except (AttributeError, ImportError) as err:
            missing.append(f"{name}: {err}")
    assert not missing, "\n".join(missing)
    assert {"robot_preset", "cycle_preset", "Problem", "Timing", "run_sweep", "LawEvaluator", "optimize_design",
            "StudyConfig", "TrainConfig", "OptimizerConfig", "verify", "shaper_profiles", "STAGES"} <= set(jf.__all__)
    assert jf.StudyConfig().train.optimizer == jf.OptimizerConfig(steps=50, decay=True, patience=40, label="design")


def test_importing_the_package_imports_no_jax():
    code = ("import sys, jaxflex; assert 'jax' not in sys.modules; jaxflex.StudyConfig(); "
            "assert 'jax' not in sys.modules")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr


def test_the_gradient_strategy_is_a_value_with_one_build_setting():
    """How the gradient is computed is a value passed in (``OneProgram``, ``Staged``) with one build
    setting: "quick" or "fast", or None for the optimizer to choose by its number of steps."""
    import pytest

    import jaxflex as jf
    from jaxflex.optimize.gradient import HOT_STEPS, resolved

    assert resolved(jf.Staged(), HOT_STEPS).build == "fast" and resolved(jf.Staged(), HOT_STEPS - 1).build == "quick"
    assert resolved(jf.OneProgram(build="quick"), 10 * HOT_STEPS).build == "quick"      # an explicit build stays
    for bad in ("hot", True):
        with pytest.raises(ValueError, match="build"):
            jf.Staged(build=bad)
    with pytest.raises(ValueError, match="mode"):
        jf.OneProgram(mode="sideways")


def test_float32_mode_is_refused_with_what_to_do():
    """Without float64 (JAX's default), building a robot, which every computation starts with, stops
    with an error naming the switch, instead of computing the physics in float32."""
    code = "import jaxflex as jf; jf.robot_preset()"
    env = {k: v for k, v in __import__("os").environ.items() if k != "JAX_ENABLE_X64"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode != 0 and "jax_enable_x64" in out.stderr and "float32" in out.stderr, out.stderr
    ok = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                        env={**env, "JAX_ENABLE_X64": "1"})
    assert ok.returncode == 0, ok.stderr


def test_importing_the_plotting_module_keeps_the_users_matplotlib_backend():
    """``jaxflex.plotting`` draws into whatever backend the user chose (svg here): importing it
    must not switch to Agg, which would break inline, svg, ipympl and widget users."""
    code = ("import matplotlib; matplotlib.use('svg'); import jaxflex.plotting; "
            "print(matplotlib.get_backend())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "svg", (out.stdout, out.stderr)
