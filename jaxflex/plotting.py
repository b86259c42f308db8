"""Matplotlib figures of trajectories, spectra and simulation results.

Every function takes plain arrays (numpy or JAX) and returns a ``matplotlib.figure.Figure``; saving
is the caller's business (``fig.savefig``). Importing this module leaves matplotlib's backend as
the user set it (inline, svg, ipympl, a window); the ``jaxflex`` command line, which only writes
files, selects Agg itself unless ``MPLBACKEND`` is set.
"""
from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

PROFILE_STYLE = {"poly7": "-", "bang_bang": "--", "trap_1_4": "-.", "trap_1_8": ":"}
BLEND_COLOR = {"lame": "C0", "clothoid": "C1", "polar": "C2"}


def motion_laws(eta, laws: dict):
    """Fig. 7: S, S', S'', S''' versus eta for each law (dict name -> LawValues of arrays)."""
    fig, axes = plt.subplots(2, 2, figsize=(9, 6), sharex=True)
    titles = ["position S", "velocity S'", "acceleration S''", "jerk S'''"]
    for name, v in laws.items():
        for ax, y in zip(axes.flat, v):
            ax.plot(eta, np.asarray(y), PROFILE_STYLE.get(name, "-"), label=name)
    for ax, t in zip(axes.flat, titles):
        ax.set_title(t)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("normalized time eta = t / tf")
    axes[0, 0].legend()
    fig.suptitle("Motion laws (tf = 1, derivatives w.r.t. eta)")
    fig.tight_layout()
    return fig


def blends_overlay(curves: dict, corner=(0.0, 0.025)):
    """Fig. 6: blend curves (dict name -> (N, 2) points in the blend frame [m]) with the sharp corner."""
    fig, ax = plt.subplots(figsize=(5.5, 5))
    cx, cy = 1e3 * np.asarray(corner)
    ax.plot([0, cx, cx + 30], [0, cy, cy], "k:", lw=1, label="Adept corner")
    for name, pts in curves.items():
        pts = np.asarray(pts) * 1e3
        ax.plot(pts[:, 0], pts[:, 1], color=BLEND_COLOR.get(name.split()[0]), label=name)
    ax.set_aspect("equal")
    ax.set_xlabel("x along the traverse [mm]")
    ax.set_ylabel("y along the lift [mm]")
    ax.set_title("Corner blends, d = e = 25 mm")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return fig


def psd_panels(freqs, series: dict, title: str, ylabel: str = "PSD [(rad/s^2)^2/Hz]",
               panels: dict | None = None, fmin: float = 1.0, fmax: float | None = None):
    """Log-log PSD curves. ``series`` maps label -> (n_joints, F) PSD; one subplot per joint, or per
    group when ``panels`` maps panel title -> list of labels."""
    f = np.asarray(freqs)
    keep = f >= fmin if fmax is None else (f >= fmin) & (f <= fmax)
    first = np.asarray(next(iter(series.values())))
    if panels is None:
        n = first.shape[0]
        fig, axes = plt.subplots(1, n, figsize=(5.5 * n, 4.2), sharey=True, squeeze=False)
        for j, ax in enumerate(axes[0]):
            for label, p in series.items():
                ax.loglog(f[keep], np.asarray(p)[j][keep], label=label, lw=1)
            ax.set_title(f"joint {j + 1}")
    else:
        fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 4.2), sharey=True,
                                 squeeze=False)
        for ax, (ptitle, labels) in zip(axes[0], panels.items()):
            for label in labels:
                p = np.asarray(series[label])
                ax.loglog(f[keep], p[0][keep], label=label, lw=1)
            ax.set_title(ptitle)
    for ax in axes[0]:
        ax.set_xlabel("frequency [Hz]")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    axes[0, 0].set_ylabel(ylabel)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def lines(x, series: dict, xlabel: str, ylabel: str, title: str, logy: bool = False, styles=None):
    """Generic line plot of several series sharing x."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for label, y in series.items():
        style = (styles or {}).get(label, "-")
        ax.plot(np.asarray(x), np.asarray(y), style, label=label, lw=1.2)
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def tracking_errors(t, t_dwell, e_norm: dict, e_dwell: dict, title: str):
    """Fig. 12: |e| [mm] over the motion (left) and |e - e_static| over the dwell (right), one line
    per 'blend/profile' key, one colour per profile and one line style per blend."""
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2), sharey=False)
    colors = {"poly7": "C0", "bang_bang": "C1", "trap_1_4": "C2", "trap_1_8": "C3"}
    styles = {"lame": "-", "clothoid": "--", "polar": ":"}
    for key, v in e_norm.items():
        blend, prof = key.split("/")
        a.plot(t, v, styles.get(blend, "-"), color=colors.get(prof), lw=1, label=key)
        b.plot(t_dwell, e_dwell[key], styles.get(blend, "-"), color=colors.get(prof), lw=0.8)
    a.set(xlabel="t [s]", ylabel="|e| [mm]", title="during the motion")
    b.set(xlabel="t [s]", ylabel="|e - e_static| [mm]", title="dwell at the place pose", yscale="log")
    a.legend(fontsize=6, ncol=3)
    fig.suptitle(title)
    fig.tight_layout()
    return fig
