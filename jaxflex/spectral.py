"""Power spectral density by Welch's method (Hann window, 50 % overlap, one-sided), in JAX.

Used for the spectral content of joint accelerations (paper Figs. 8, 10, 11) and of the end-effector
error. ``jax.scipy.signal.welch`` with the paper figures' settings, so it also runs inside jit/vmap.
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jax.scipy.signal  # noqa: F401  (the submodule)
import numpy as np


def welch(x, fs: float, nperseg: int | None = None):
    """One-sided PSD of x along its last axis.

    Args:
        x: signal (..., N), units U.
        fs: sampling frequency [Hz].
        nperseg: segment length (static; default min(N, 1024)); segments overlap by half, each is
            mean-detrended and Hann-windowed.
    Returns:
        freqs (nperseg // 2 + 1,) [Hz] and psd (..., nperseg // 2 + 1) [U^2/Hz]. The PSD integrates
        (sum * df) to the mean square of the detrended signal (Parseval), as scipy.signal.welch.
    """
    x = jnp.asarray(x, dtype=float)
    n = x.shape[-1]
    nperseg = int(min(n, 1024) if nperseg is None else nperseg)
    if nperseg < 2 or nperseg > n:
        raise ValueError(f"nperseg must be in [2, {n}], got {nperseg}")
    return _welch(x, jnp.asarray(fs, dtype=x.dtype), nperseg)


@functools.partial(jax.jit, static_argnames=("nperseg",))
def _welch(x, fs, nperseg: int):
    """One compiled program per signal shape and segment length (called eagerly, the op-by-op
    evaluation compiled and dispatched every primitive on its own)."""
    return jax.scipy.signal.welch(x, fs=fs, window="hann", nperseg=nperseg, noverlap=nperseg - nperseg // 2,
                                  detrend="constant", return_onesided=True, scaling="density",
                                  axis=-1, average="mean")


def dominant_frequencies(freqs, psd, k: int = 3, fmin: float = 0.0):
    """The k frequencies [Hz] of the largest local maxima of a 1-D PSD above fmin (numpy, host)."""
    f, p = np.asarray(freqs), np.asarray(psd)
    inner = (p[1:-1] > p[:-2]) & (p[1:-1] >= p[2:]) & (f[1:-1] >= fmin)
    peaks = np.nonzero(inner)[0] + 1
    order = peaks[np.argsort(p[peaks])[::-1]]
    return f[order[:k]]
