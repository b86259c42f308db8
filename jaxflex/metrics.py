"""Per-run metrics (docs/conventions.md#metrics) from a simulation ``Series`` (pure jnp: jit- and
vmap-friendly).

e = X_flexible - X_desired at the end effector. Over the motion [0, tf]: ``max_torque_nm`` max |tau|
over both motors, ``rms_acc_error`` RMS of |e''| [m/s^2], ``max_deflection_mm`` max |e| (includes the
static sag). At tf (right limit: the state the dwell starts from): ``residual_pos_mm`` |e|,
``residual_vel`` |e'| [m/s], ``residual_acc`` |e''| [m/s^2], ``residual_acc_low`` the part of |e''|
carried by the modes below 1 kHz [m/s^2] (``simulate.low_mode_acceleration``). Over the dwell:
``dwell_residual_mm`` max |e - e_static| (e_static: static sag at the place pose). ``residual_energy`` [J]: vibration
energy of the elastic state at tf relative to the static equilibrium at the place pose.

Acceleration metrics contain every mode of the model (up to ~18 kHz), undamped, evaluated exactly
at the sample instants: no filter and no numerical damping. They converge in dt because the rollout's
second pass makes the coefficients continuous in time (``jaxflex.simulate``): frozen coefficients that
jump at interval boundaries would kick the kHz modes artificially. ``residual_acc_low`` is the part
of the residual acceleration carried by the modes below 1 kHz (what a sensor with a 1 kHz bandwidth
would see).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

METRICS = ("max_torque_nm", "rms_acc_error", "max_deflection_mm", "residual_pos_mm", "residual_vel",
           "residual_acc", "residual_acc_low", "dwell_residual_mm", "residual_energy")

UNITS = {"max_torque_nm": "N m", "rms_acc_error": "m/s^2", "max_deflection_mm": "mm",
         "residual_pos_mm": "mm", "residual_vel": "m/s", "residual_acc": "m/s^2",
         "residual_acc_low": "m/s^2", "dwell_residual_mm": "mm", "residual_energy": "J"}


def _norm(v):
    return jnp.sqrt(jnp.sum(v * v, axis=-1))


def metrics(series) -> dict:
    """Dict metric name -> scalar for one run."""
    return {
        "max_torque_nm": jnp.max(jnp.abs(series.tau)),
        "rms_acc_error": jnp.sqrt(jnp.mean(jnp.sum(series.edd**2, axis=-1))),
        "max_deflection_mm": 1e3 * jnp.max(_norm(series.e)),
        "residual_pos_mm": 1e3 * _norm(series.e_dwell[0]),
        "residual_vel": _norm(series.ed_dwell[0]),
        "residual_acc": _norm(series.edd_dwell[0]),
        "residual_acc_low": _norm(series.edd_tf_low),
        "dwell_residual_mm": 1e3 * jnp.max(_norm(series.e_dwell - series.e_static[None])),
        "residual_energy": series.energy_tf,
    }


DWELL_PEAK_POWER = 16     # the order of the power mean over the dwell samples that stands in for their maximum


class Terms(NamedTuple):
    """What the objectives read of one run: the vibration energy at tf [J], the mean square dwell
    amplitude |e - e_static|^2 over the dwell [m^2], the peak motor torque |tau| over the motion
    [N m], the metrics (dict name -> scalar, ``metrics``) and ``dwell_peak`` [m^2], a smooth maximum
    of |e - e_static|^2 over the dwell samples (``dwell_peak``; None where terms are made by hand)."""

    energy: jax.Array
    dwell_ms: jax.Array
    torque: jax.Array
    metrics: dict
    dwell_peak: jax.Array | None = None


def dwell_peak(amp2, power: int = DWELL_PEAK_POWER):
    """A smooth maximum of the squared dwell amplitudes ``amp2`` (S,) [m^2]: their power mean of order
    ``power``, (mean amp2^power)^(1/power). It lies between the mean and the maximum (the square of
    ``dwell_residual_mm``), within a factor (1/S)^(1/power) of the maximum, and, unlike the maximum, its
    gradient is spread over the samples near the peak. Computed relative to the maximum (held constant
    in the derivative, which it cancels from exactly), so that amp2^power cannot underflow; 0, with a
    zero gradient, for a dwell at rest."""
    top = jax.lax.stop_gradient(jnp.max(amp2))
    m = jnp.mean((amp2 / jnp.where(top > 0, top, 1.0)) ** power)
    return jnp.where(top > 0, top * jnp.where(top > 0, m, 1.0) ** (1.0 / power), 0.0)    # 0, not NaN, at rest


def terms(series) -> Terms:
    """The ``Terms`` of one run's ``Series``."""
    amp = series.e_dwell - series.e_static[None]
    amp2 = jnp.sum(amp * amp, axis=-1)
    return Terms(series.energy_tf, jnp.mean(amp2), jnp.max(jnp.abs(series.tau)), metrics(series), dwell_peak(amp2))
