"""Bad inputs raise clear ValueErrors before any compilation (docs/conventions.md#bad-input)."""
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import combinations as combinations_mod
from jaxflex.path import make_cycle
from jaxflex.robot import cycle_preset, make_robot, robot_preset
from jaxflex.profiles import make_profile, trapezoid, shaped
from jaxflex.combinations import sample_combinations
from jaxflex.trajectory import time_grid

ROBOT, CYCLE = robot_preset(), cycle_preset()
T = jnp.linspace(0.0, 0.43, 11)


def _no_compile(call, match):
    before = combinations_mod.cache_size()
    with pytest.raises(ValueError, match=match):
        call()
    assert combinations_mod.cache_size() == before


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
    with pytest.raises(ValueError, match="order must be 2, 3 or 4"):
        shaped(jnp.ones(3), order=5)
    with pytest.raises(ValueError, match="time steps must be >= 1"):
        time_grid(0.4, 0)
    with pytest.raises(ValueError, match="unknown motion profile"):
        make_profile("s_curve")


# --------------------------------------------------------------- every public entry point that compiles


@pytest.fixture
def compilations():
    """Counts XLA compilations (``jax.monitoring``) while the test runs."""
    from jax import monitoring

    count = [0]

    def listener(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            count[0] += 1

    monitoring.register_event_duration_secs_listener(listener)
    yield count
    monitoring.unregister_event_duration_listener(listener)


def _entry_points():
    """(name, callable taking keyword overrides, {argument: bad values}) for every public entry
    point that compiles."""
    from jaxflex.design_sweep import DesignSweepConfig, sweep_designs
    from jaxflex.designs import design
    from jaxflex.experiments import bench, reproduce
    from jaxflex.model_sets import model_set
    from jaxflex.optimize.cycle_time import cycle_time_study
    from jaxflex.optimize.objective import Scales, encode
    from jaxflex.optimize.study import optimize_design
    from jaxflex.optimize.training import Training, train_design, train_law
    from jaxflex.problem import Problem, Timing
    from jaxflex.simulate import Grid
    from jaxflex.sweep import Case, SweepConfig, run_sweep
    from jaxflex.uncertainty import Box

    grid = Grid(coarse=96, fine=4, dwell_steps=100)
    bad_times = [0.0, -0.43, float("nan"), float("inf")]
    bad_payloads = [-6.0, float("nan"), float("inf")]
    one = jnp.ones(1)
    scales = Scales(one, one, one)
    models = model_set(ROBOT, [6.0])
    xs = jax_tree_stack([design(coef=np.ones(4))] * 2)
    params = encode(CYCLE, design(coef=np.ones(4)))

    def sweep(tf=0.43, payload=6.0, **kw):
        return run_sweep(ROBOT, CYCLE, [Case(payload, tf)], SweepConfig(**kw))

    class _Evaluator:            # what train_law reads of its evaluator (no tables built)
        def __init__(self, tf=0.43, dwell=0.1):
            self.models, self.grid, self.tf, self.dwell, self.tables, self.path = models, grid, tf, dwell, None, None

    return [
        ("run_sweep", sweep, {"tf": bad_times, "payload": bad_payloads, "dwell": bad_times, "dt": bad_times,
                              "repeats": [0, -1, 1.5], "profiles": [("poly5",)], "blends": [("spline",)]}),
        ("sweep_designs", lambda tf=0.43, dwell=0.1, **kw: sweep_designs(
            ROBOT, CYCLE, xs, DesignSweepConfig(Timing(tf, dwell, grid), **kw)),
         {"tf": bad_times, "dwell": bad_times, "chunk": [0, -4], "blend": ["spline"]}),
        ("optimize_design", lambda **kw: optimize_design(
            Problem(ROBOT, CYCLE, kw.pop("payloads", (6.0,)), Timing(kw.pop("tf", 0.43), kw.pop("dwell", 0.1))),
            _study_config(**kw)),
         {"tf": bad_times, "dwell": bad_times, "payloads": [(0.0,), (-6.0,), (float("nan"),), (float("inf"),), ()],
          "steps": [-1, 2.5, float("nan")], "learning_rate": bad_times, "n_coef": [0, -2],
          "train": ["everything"], "blend": ["spline", "clothoid"], "box_points": [0, 2, -3],
          "box_samples": [-1, 2.5], "robust_power": [0.0, -8.0, float("nan")],
          "box": [Box(young=-0.05), Box(payload=1.5), Box(damping=(0.01, 0.0)), Box(length=float("nan"))]}),
        ("train_design", lambda tf=0.43, dwell=0.1, **kw: train_design(
            Training(models, CYCLE, Timing(tf, dwell, grid), scales), params, _train_config(**kw)),
         {"tf": bad_times, "dwell": bad_times, "steps": [-1, 0.5], "learning_rate": bad_times}),
        ("train_law", lambda tf=0.43, dwell=0.1, **kw: train_law(_Evaluator(tf, dwell), scales, np.ones(4),
                                                                 _train_config(**kw)),
         {"tf": bad_times, "dwell": bad_times, "steps": [-1], "learning_rate": bad_times}),
        ("cycle_time_study", lambda **kw: cycle_time_study(
            Problem(ROBOT, CYCLE, (kw.pop("payloads", 6.0),), Timing(kw.pop("tf", 0.43))), kw.pop("tfs", (0.43, 0.4)),
            _study_config(**kw)),
         {"payloads": [0.0, *bad_payloads], "tf": bad_times, "tfs": [(0.43, 0.0), (float("nan"),), ()],
          "steps": [-1], "learning_rate": bad_times, "train": ["all"], "box_points": [4],
          "box": [Box(rotor=-0.1)]}),
        ("bench", lambda **kw: bench.compute(**kw), {"repeats": [0, -1, 2.5]}),
        ("reproduce", lambda **kw: reproduce.run(**kw), {"out": ["", None]}),
    ]


_OPTIMIZER = ("steps", "learning_rate")         # the flat names of the cases: their nested fields
_TRAIN = {"robust_power": "power", "blend": "blend"}


def _train_config(**kw):
    from jaxflex.optimize.config import TrainConfig

    return TrainConfig().with_optimizer(**{k: kw.pop(k) for k in _OPTIMIZER if k in kw})


def _study_config(**kw):
    import dataclasses

    from jaxflex.optimize.config import StudyConfig

    c = StudyConfig().with_optimizer(**{k: kw.pop(k) for k in _OPTIMIZER if k in kw})
    c = c.with_train(**{_TRAIN[k]: kw.pop(k) for k in list(kw) if k in _TRAIN})
    if "train" in kw:
        kw["training_set"] = kw.pop("train")
    return dataclasses.replace(c, **kw)


def jax_tree_stack(items):
    import jax

    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *items)


def _cases():
    for name, _, bad in _entry_points():
        for arg, values in bad.items():
            for v in values:
                yield pytest.param(name, arg, v, id=f"{name}-{arg}={v!r}")


@pytest.mark.parametrize("name, arg, value", list(_cases()))
def test_every_entry_point_rejects_bad_values_naming_them_before_compiling(name, arg, value, compilations):
    """Zero, negative, NaN or infinite times, steps, rates and payloads, and unknown names,
    are rejected with a ValueError that names the argument, and nothing is compiled first."""
    call = next(fn for n, fn, _ in _entry_points() if n == name)
    compilations[0] = 0
    with pytest.raises(ValueError) as err:
        call(**{arg: value})
    text = str(err.value)
    expected = {"payloads": "payload", "blends": "blend", "profiles": "profile", "train": "training set",
                "tf_ref": "tf", "tfs": "tfs", "blend": "blend", "robust_power": "power"}.get(arg, arg)
    assert expected in text, (name, arg, value, text)
    assert compilations[0] == 0, f"{name}({arg}={value!r}) compiled {compilations[0]} programs before rejecting it"


def test_configured_entry_points_refuse_a_wrong_configuration(compilations):
    """run_sweep, sweep_designs, train_design and train_law take their options as one configuration
    value: another type there, or a training timing without its grid, is refused before anything
    compiles."""
    from jaxflex.design_sweep import sweep_designs
    from jaxflex.model_sets import model_set
    from jaxflex.optimize.objective import Scales, encode
    from jaxflex.optimize.config import TrainConfig
    from jaxflex.optimize.training import Training, train_design, train_law
    from jaxflex.designs import design
    from jaxflex.problem import Timing
    from jaxflex.sweep import PAPER_CASES, run_sweep

    one = jnp.ones(1)
    training = Training(model_set(ROBOT, [6.0]), CYCLE, Timing(0.43, 0.1), Scales(one, one, one))
    params = encode(CYCLE, design(coef=np.ones(4)))
    compilations[0] = 0
    with pytest.raises(TypeError, match="config must be a SweepConfig, got dict"):
        run_sweep(ROBOT, CYCLE, PAPER_CASES, {"timed": False})
    with pytest.raises(TypeError):
        run_sweep(ROBOT, CYCLE, PAPER_CASES, timed=False)          # the options live in SweepConfig
    with pytest.raises(ValueError, match="needs the timing's grid"):
        train_design(training, params, TrainConfig().with_optimizer(steps=1))
    with pytest.raises(TypeError):
        train_law(None, None, np.ones(4), steps=1)                      # the options live in TrainConfig
    with pytest.raises(TypeError, match="config must be a DesignSweepConfig, got Timing"):
        sweep_designs(ROBOT, CYCLE, None, Timing(0.43, 0.1))
    assert compilations[0] == 0


@pytest.mark.parametrize("kwargs, match", [
    (dict(method="rk45"), r"unknown full-model method 'rk45'; choose one of exprb3, rk4"),
    (dict(method="rk4", dt=5e-5), r"RK4 reference step dt=5e-05 s is above its stability limit"),
    (dict(tf=float("inf")), r"tf must be finite \[s\]"),
    (dict(dwell=0.0), r"dwell must be > 0 \[s\]"),
    (dict(dt=-1e-5), r"dt must be > 0 \[s\]"),
    (dict(dwell_dt=float("nan")), r"dwell_dt must be finite \[s\]"),
])
def test_bad_full_model_arguments(kwargs, match):
    """The full model's reference rollout rejects bad options before it compiles anything."""
    from jaxflex import reference
    from jaxflex.path import make_path

    args = dict(tf=0.43, dwell=0.1) | kwargs
    programs = (reference._start, reference._advance, reference._ends, reference._joint_samples)
    before = [p._cache_size() for p in programs]
    with pytest.raises(ValueError, match=match):
        reference.reference_rollout(ROBOT, make_path(CYCLE, "lame", 0.025), make_profile("poly7"),
                                    progress=False, **args)
    assert [p._cache_size() for p in programs] == before


def test_the_model_range_refuses_a_sag_or_a_motion_beyond_small_deflections():
    """The small-deflection bound (docs/conventions.md#model-range): the cantilever estimate for the
    paper's robot (Table 3: l2 0.38079 m, d 35 mm, E 70 GPa, rho 2710 kg/m^3) with 6 kg under
    gravity, computed here by hand, is 5.86e-4 of the link; payloads of 500 kg pass and 600 kg are
    refused (the bound, 5 %, at about 544 kg); at 6 kg a 45 ms move passes and a 38 ms one is
    refused (about 41 ms); a sweep and an optimization study with such a case fail before any
    program compiles (1e9 kg, the 1e-300 s of a typo, included)."""
    from jaxflex.robot import check_motion_loads, deflection_ratio
    from jaxflex.sweep import Case, SweepConfig, run_sweep

    ei = 70e9 * np.pi * 0.035**4 / 64
    w = 2710.0 * np.pi * 0.035**2 / 4
    by_hand = 9.81 * (6.0 * 0.38079**2 / (3 * ei) + w * 0.38079**3 / (8 * ei))
    assert deflection_ratio(ROBOT.replace(payload=6.0), 9.81) == pytest.approx(by_hand, rel=1e-12)
    assert by_hand == pytest.approx(5.86e-4, rel=0.01)
    ROBOT.replace(payload=500.0)
    for payload in (600.0, 1e9):
        with pytest.raises(ValueError, match=r"payload .* kg: the links' static sag .* beyond the small deflections"):
            ROBOT.replace(payload=payload)
    six = ROBOT.replace(payload=6.0)
    check_motion_loads(six, CYCLE, 0.045)
    for tf in (0.038, 1e-300):
        with pytest.raises(ValueError, match=r"motion time tf .* s is too short for this robot"):
            check_motion_loads(six, CYCLE, tf)
    _no_compile(lambda: run_sweep(ROBOT, CYCLE, [Case(6.0, 0.02)], SweepConfig(timed=False)), "too short")
    _no_compile(lambda: run_sweep(ROBOT, CYCLE, [Case(1e9, 0.43)], SweepConfig(timed=False)), "static sag")
