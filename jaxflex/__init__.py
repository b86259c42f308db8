"""jaxflex: differentiable elastodynamics and trajectory design for a flexible five-bar robot.

Everything a researcher uses is reachable from here (``import jaxflex as jf``), grouped as

- the robot, its cycle and paths: ``robot_preset``, ``make_robot``, ``cycle_preset``, ``make_cycle``,
  from and to TOML files or dicts ``load_robot``, ``load_cycle``, ``robot_toml``, ``cycle_toml``,
  ``robot_from_dict``, ``robot_to_dict``, ``cycle_from_dict``, ``cycle_to_dict``,
  ``make_path``, ``make_profile``, ``shaped``, ``time_grid``, ``sample_combinations`` and the module
  ``trajectory`` (``jf.trajectory.trajectory``: one trajectory's task and joint samples);
- the problem: ``Problem``, ``Timing``, ``Grid``, ``default_grid``;
- simulation: ``run_sweep`` (the paper's combinations), ``LawEvaluator`` (any law on a model set),
  ``design_rollout``, the stage list ``STAGES`` with its ``RolloutModel`` and ``RolloutState`` and
  the module ``rollout`` (``jf.rollout.rollout``: one trajectory from its tables), ``sweep_designs``,
  ``METRICS``, ``UNITS`` and the module ``metrics`` (``jf.metrics.metrics``: the metrics of a
  series), ``modes_at_point``, ``reference_rollout`` (the full nonlinear model);
- models: ``model_set``, ``models_of``, ``ModelId``, ``Box`` (the uncertainty box), ``richer``;
- optimization: ``optimize_design`` with ``StudyConfig`` (holding ``TrainConfig``, holding
  ``OptimizerConfig``), ``cycle_time_study``, ``train_design``, ``train_law``, ``minimize`` and the
  gradient strategies ``OneProgram`` and ``Staged``;
- baselines and checks: ``shaper_profiles``, ``ruckig_samples``, ``verify``.

The names load on first use (``import jaxflex`` itself imports no JAX). jaxflex computes in
float64: enable it before anything else, ``jax.config.update("jax_enable_x64", True)``.
Conventions (frames, units, metrics, the uncertainty box, file formats): docs/conventions.md.
"""
import importlib

__version__ = "0.2.0"

# name -> the module that defines it
_PUBLIC = {
    # the robot, its cycle, paths, motion laws and trajectories
    "Robot": "jaxflex.robot", "make_robot": "jaxflex.robot", "robot_preset": "jaxflex.robot",
    "cycle_preset": "jaxflex.robot", "Cycle": "jaxflex.path", "make_cycle": "jaxflex.path",
    "Path": "jaxflex.path", "make_path": "jaxflex.path", "Profile": "jaxflex.profiles",
    "make_profile": "jaxflex.profiles", "shaped": "jaxflex.profiles", "zv": "jaxflex.profiles",
    "zvd": "jaxflex.profiles", "profile_eval": "jaxflex.profiles", "profile_values": "jaxflex.profiles",
    "trajectory": "jaxflex.trajectory", "time_grid": "jaxflex.trajectory",
    "sample_combinations": "jaxflex.combinations", "load_robot": "jaxflex.robot_files",
    "load_cycle": "jaxflex.robot_files", "robot_from_dict": "jaxflex.robot_files",
    "robot_to_dict": "jaxflex.robot_files", "cycle_from_dict": "jaxflex.robot_files",
    "cycle_to_dict": "jaxflex.robot_files", "robot_toml": "jaxflex.robot_files", "cycle_toml": "jaxflex.robot_files", "PRESETS": "jaxflex.names", "BLENDS": "jaxflex.names",
    "DESIGN_BLENDS": "jaxflex.names", "PROFILES": "jaxflex.names",
    # the problem and its discretization
    "Problem": "jaxflex.problem", "Timing": "jaxflex.problem", "Grid": "jaxflex.simulate",
    "default_grid": "jaxflex.sweep",
    # simulation
    "Case": "jaxflex.sweep", "PAPER_CASES": "jaxflex.sweep", "SweepConfig": "jaxflex.sweep",
    "run_sweep": "jaxflex.sweep", "sweep_tables": "jaxflex.sweep", "plotting": "jaxflex.plotting",
    "LawEvaluator": "jaxflex.engine", "rollout": "jaxflex.rollout", "design_rollout": "jaxflex.rollout",
    "STAGES": "jaxflex.rollout", "RolloutModel": "jaxflex.rollout", "RolloutState": "jaxflex.rollout",
    "Design": "jaxflex.designs", "design": "jaxflex.designs", "design_path": "jaxflex.designs",
    "sweep_designs": "jaxflex.design_sweep", "DesignSweepConfig": "jaxflex.design_sweep",
    "metrics": "jaxflex.metrics", "METRICS": "jaxflex.metrics", "UNITS": "jaxflex.metrics",
    "modes_at_point": "jaxflex.frequencies", "reference_rollout": "jaxflex.reference",
    "path_tables": "jaxflex.tables", "build_workspace": "jaxflex.tables",
    # models
    "model_set": "jaxflex.model_sets", "models_of": "jaxflex.model_sets", "ModelSet": "jaxflex.model_sets",
    "ModelId": "jaxflex.uncertainty", "Box": "jaxflex.uncertainty", "richer": "jaxflex.model",
    # optimization
    "optimize_design": "jaxflex.optimize.study", "DesignStudy": "jaxflex.optimize.study",
    "StudyConfig": "jaxflex.optimize.config", "TrainConfig": "jaxflex.optimize.config",
    "OptimizerConfig": "jaxflex.optimize.config", "cycle_time_study": "jaxflex.optimize.cycle_time",
    "Training": "jaxflex.optimize.training", "train_design": "jaxflex.optimize.training",
    "train_law": "jaxflex.optimize.training", "training_models": "jaxflex.optimize.training",
    "minimize": "jaxflex.optimize.loop", "OneProgram": "jaxflex.optimize.gradient",
    "Staged": "jaxflex.optimize.staged", "DesignObjective": "jaxflex.optimize.objective",
    "LawObjective": "jaxflex.optimize.objective", "Scales": "jaxflex.optimize.objective",
    # baselines and checks
    "shaper_profiles": "jaxflex.optimize.baselines", "ruckig_samples": "jaxflex.optimize.baselines",
    "paper_sweep": "jaxflex.optimize.evaluation", "evaluation_sets": "jaxflex.optimize.evaluation",
    "verify": "jaxflex.optimize.verification",
}

__all__ = sorted(_PUBLIC) + ["__version__"]


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'jaxflex' has no attribute {name!r}")
    value = importlib.import_module(module)
    if module != f"{__name__}.{name}":          # a module of the same name is itself the public name
        value = getattr(value, name)
    globals()[name] = value             # later accesses skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_PUBLIC))
