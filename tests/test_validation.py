"""Bad inputs raise clear ValueErrors before any compilation (SPEC 8)."""
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import trajectory as trajectory_mod
from jaxflex.path import make_cycle
from jaxflex.robot import cycle_preset, make_robot, robot_preset
from jaxflex.profiles import make_profile, trapezoid, shaped
from jaxflex.trajectory import sample_combinations, time_grid

ROBOT, CYCLE = robot_preset(), cycle_preset()
T = jnp.linspace(0.0, 0.43, 11)


def _no_compile(call, match):
    before = trajectory_mod._combinations_jit._cache_size()
    with pytest.raises(ValueError, match=match):
        call()
    assert trajectory_mod._combinations_jit._cache_size() == before


@pytest.mark.parametrize("kwargs, match", [
    (dict(d=0.03), r"d = 0.03 m exceeds the lift height h = 0.025 m"),
    (dict(d=0.02, e=0.2), r"e = 0.2 m and e2 = 0.2 m exceed the traverse l = 0.35 m"),
    (dict(n=1.5), r"Lamé order n must be >= 2"),
    (dict(d=-0.01), r"d must be > 0"),
    (dict(d=float("nan")), r"d must be finite"),
    (dict(blends=("lame", "spline")), r"unknown blend 'spline'; choose one of lame, clothoid, polar"),
    (dict(profiles=("poly5",)), r"unknown motion profile 'poly5'"),
])
def test_bad_path_arguments(kwargs, match):
    _no_compile(lambda: sample_combinations(ROBOT, CYCLE, 0.43, T, **kwargs), match)


@pytest.mark.parametrize("tf", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_motion_time(tf):
    _no_compile(lambda: sample_combinations(ROBOT, CYCLE, tf, T), r"motion time tf must be finite and > 0")


def test_unreachable_pick_point():
    far = make_cycle((-0.45, 0.55), (0.1, 0.55))
    _no_compile(lambda: sample_combinations(ROBOT, far, 0.43, T),
                r"pick point \(-0.4500, 0.5500\) m is unreachable by arm 1 .* exceeds l1 \+ l2")


def test_bad_robot_and_cycle_parameters():
    with pytest.raises(ValueError, match="payload must be >= 0"):
        robot_preset(payload=-1.0)
    with pytest.raises(ValueError, match="young must be > 0"):
        robot_preset(young=0.0)
    with pytest.raises(ValueError, match="l1 must be finite"):
        robot_preset(l1=float("nan"))
    with pytest.raises(ValueError, match="working modes"):
        make_robot(modes=(1, 0), assembly=1)
    with pytest.raises(ValueError, match="number of assumed modes"):
        robot_preset(n_bending=0)
    with pytest.raises(ValueError, match="unknown preset 'square'"):
        robot_preset("square")
    with pytest.raises(ValueError, match="perpendicular"):
        make_cycle((-0.1, 0.3), (0.1, 0.3), lift=(np.sqrt(0.5), np.sqrt(0.5)))
    with pytest.raises(ValueError, match="lift height h must be > 0"):
        make_cycle((-0.1, 0.3), (0.1, 0.3), h=0.0)


def test_bad_profiles():
    with pytest.raises(ValueError, match=r"ta must be in \(0, 1/2\]"):
        trapezoid(0.6)
    with pytest.raises(ValueError, match="order must be 2 or 3"):
        shaped(jnp.ones(3), order=4)
    with pytest.raises(ValueError, match="time steps must be >= 1"):
        time_grid(0.4, 0)
    with pytest.raises(ValueError, match="unknown motion profile"):
        make_profile("s_curve")
