"""Input-shaped motion laws (ZV / ZVD baselines of the optimization study)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import profiles
from jaxflex.profiles import input_shaped, make_profile, zv, zvd

# the law evaluated as one compiled program per law kind and shape (evaluated op by op, each of its
# hundreds of operations compiles a kernel of its own)
profile_eval = jax.jit(profiles.profile_eval, static_argnames="side")

TF = 0.43


def _residual_amplitude(profile, freq_hz, n=200001):
    """Free-vibration amplitude after the motion of an undamped oscillator driven by the law's
    acceleration: |int_0^tf S''(t) exp(-i w t) dt| / w = |int_0^tf S'(t) exp(-i w t) dt| (by parts,
    S' = 0 at both ends; the velocity is continuous, so the trapezoid rule converges as h^2)."""
    eta = np.linspace(0.0, 1.0, n)
    vel = np.asarray(profile_eval(profile, jnp.asarray(eta)).ds) / TF
    t = eta * TF
    integrand = vel * np.exp(-2j * np.pi * freq_hz * t)
    return abs(np.sum((integrand[1:] + integrand[:-1]) * np.diff(t)) / 2)


@pytest.mark.parametrize("shaper", [zv, zvd])
@pytest.mark.parametrize("base", ["poly7", "trap_1_4"])
def test_shaped_law_boundary_conditions_and_derivatives(shaper, base):
    p = shaper(base, 58.0, TF)
    v0, v1 = profile_eval(p, jnp.asarray(0.0)), profile_eval(p, jnp.asarray(1.0), -1)
    assert abs(float(v0.s)) < 1e-14 and abs(float(v1.s) - 1) < 1e-14     # round-off of the polynomial
    assert abs(float(v0.ds)) < 1e-12 and abs(float(v1.ds)) < 1e-12
    eta = jnp.linspace(0.013, 0.987, 301)     # avoid the trapezoid's jump instants
    v, h = profile_eval(p, eta), 1e-6
    fd = (profile_eval(p, eta + h).s - profile_eval(p, eta - h).s) / (2 * h)
    np.testing.assert_allclose(v.ds, fd, atol=1e-7 * float(jnp.max(v.ds)))
    assert float(jnp.min(jnp.diff(profile_eval(p, jnp.linspace(0, 1, 2001)).s))) >= 0.0


@pytest.mark.parametrize("shaper, limit", [(zv, 1e-6), (zvd, 1e-6)])
def test_shaper_cancels_the_tuned_mode(shaper, limit):
    """At the tuned frequency the shaped law leaves no residual vibration (the base law does); ZVD
    also tolerates a 5 % frequency error far better than ZV (its residual is flat in frequency)."""
    f = 58.0
    base = _residual_amplitude(make_profile("trap_1_4"), f)
    assert base > 1e-5
    assert _residual_amplitude(shaper("trap_1_4", f, TF), f) < limit * base
    if shaper is zvd:
        off_zv = _residual_amplitude(zv("trap_1_4", f, TF), 1.05 * f)
        off_zvd = _residual_amplitude(zvd("trap_1_4", f, TF), 1.05 * f)
        assert off_zvd < 0.3 * off_zv


def test_bad_shaper_input_is_rejected():
    with pytest.raises(ValueError, match="ascend from 0"):
        input_shaped("poly7", [0.5, 0.5], [0.1, 0.2])
    with pytest.raises(ValueError, match="sum to 1"):
        input_shaped("poly7", [0.5, 0.6], [0.0, 0.2])
    with pytest.raises(ValueError, match="unknown motion profile"):
        input_shaped("nope", [1.0], [0.0])
