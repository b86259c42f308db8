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
