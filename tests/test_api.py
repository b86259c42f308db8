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
