"""Matplotlib figures of trajectories, spectra and simulation results.

Every function takes plain arrays (numpy or JAX) and returns a ``matplotlib.figure.Figure``; saving
is the caller's business (``fig.savefig``). Importing this module leaves matplotlib's backend as
the user set it (inline, svg, ipympl, a window); the ``jaxflex`` command line, which only writes
files, selects Agg itself unless ``MPLBACKEND`` is set.

The figures are sized for a paper: one column (``COLUMN_WIDTH``) or two (``PAGE_WIDTH``) wide, so
that their text keeps its size in print (legends at ``LEGEND_SIZE`` pt or more, ticks and labels at
matplotlib's 10 pt); legends and titles show readable names (``jaxflex.names.display_name``), not
the code names of blends and laws. Crowded legends go below the axes (``legend_below``), with the
figures laid out by matplotlib's constrained layout, which makes room for them.
"""
from __future__ import annotations

import math
import textwrap

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D

from jaxflex.names import display_name

PROFILE_STYLE = {"poly7": "-", "bang_bang": "--", "trap_1_4": "-.", "trap_1_8": ":"}
BLEND_COLOR = {"lame": "C0", "clothoid": "C1", "polar": "C2"}

COLUMN_WIDTH = 3.5        # one column of a two-column paper [in]
PAGE_WIDTH = 7.2          # both columns [in]
LEGEND_SIZE = 8           # legend text [pt]: the smallest text of the figures
TITLE_SIZE = 11           # figure titles (suptitle) [pt]
LINE_STYLES = ("-", "--", "-.", ":", (0, (5, 1, 1, 1, 1, 1)), (0, (8, 2)), (0, (1, 1)), (0, (3, 1, 1, 1)))
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<")


def curve_style(i: int) -> dict:
    """Line style and marker of the i-th curve of a figure (matplotlib keywords): every curve differs
    from the others in both, not in colour alone, so that curves stay apart in grayscale and where
    they overlap; the markers of successive curves are staggered along the curve (``markevery`` as
    fractions of the axes' diagonal), so that overlapping curves do not hide each other's."""
    return dict(ls=LINE_STYLES[i % len(LINE_STYLES)], marker=MARKERS[i % len(MARKERS)], ms=4,
                markevery=(0.015 * (i % 7), 0.11), markerfacecolor="none")


def text_width(text: str, size: float) -> float:
    """Width [pt] of one line of ``text`` at ``size`` pt in matplotlib's default font."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextToPath

    return TextToPath().get_text_width_height_descent(text, FontProperties(size=size), ismath=False)[0]


def legend_columns(labels, width: float, size: float = LEGEND_SIZE) -> int:
    """As many legend columns as entries of ``labels`` at ``size`` pt fit side by side in ``width``
    [in] (at least one), balanced over the rows they need."""
    labels = [str(s) for s in labels] or [""]
    longest = max(text_width(line, size) for s in labels for line in s.split("\n"))
    entry = (longest + 5.0 * size) / 72             # text, handle, its padding and the column spacing [in]
    ncol = max(1, min(len(labels), int(max(width - 0.15, 0.0) // entry)))
    rows = math.ceil(len(labels) / ncol)
    return math.ceil(len(labels) / rows)


def legend_below(fig, handles=None, labels=None, *, title=None, loc: str = "outside lower center",
                 width: float | None = None, ncol: int | None = None):
    """A figure legend below the axes at ``LEGEND_SIZE`` pt (``handles`` and ``labels``: those of the
    figure's first axes unless given), as many columns as fit ``width`` [in] (the figure's width
    unless given). ``loc``: an "outside ..." location; the figure must use the constrained layout,
    which makes room for the legend inside the figure."""
    if handles is None:
        handles, labels = fig.axes[0].get_legend_handles_labels()
    if ncol is None:
        ncol = legend_columns(labels, fig.get_figwidth() if width is None else width)
    return fig.legend(handles, labels, loc=loc, ncol=ncol, fontsize=LEGEND_SIZE, title=title,
                      title_fontsize=LEGEND_SIZE, frameon=False)


def suptitle(fig, title: str, size: float = TITLE_SIZE):
    """The figure's title at ``size`` pt, wrapped to the figure's width when it is wider."""
    title, room = str(title), fig.get_figwidth() * 72 - 2 * size           # [pt]
    width = text_width(title, size)
    if width > room:
        title = textwrap.fill(title, max(20, int(len(title) * room / width)))
    return fig.suptitle(title, fontsize=size)


def panel_grid(n: int, panel_height: float, legend_height: float = 0.0):
    """(figure, list of its ``n`` axes) of ``n`` panels in at most two columns, each column one
    ``COLUMN_WIDTH`` wide, ``panel_height`` [in] a row and ``legend_height`` [in] more for a legend
    below (``legend_below``); constrained layout, unused cells hidden."""
    cols = min(max(n, 1), 2)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(COLUMN_WIDTH * cols + 0.2 * (cols - 1),
                                                  panel_height * rows + legend_height),
                             squeeze=False, layout="constrained")
    for ax in axes.flat[n:]:
        ax.axis("off")
    return fig, list(axes.flat[:n])


def motion_laws(eta, laws: dict):
    """Fig. 7: S, S', S'', S''' versus eta for each law (dict name -> LawValues of arrays)."""
    fig, axes = plt.subplots(2, 2, figsize=(PAGE_WIDTH, 5.2), sharex=True, layout="constrained")
    titles = ["position S", "velocity S'", "acceleration S''", "jerk S'''"]
    for i, (name, v) in enumerate(laws.items()):
        style = PROFILE_STYLE.get(name, LINE_STYLES[i % len(LINE_STYLES)])
        for ax, y in zip(axes.flat, v):
            ax.plot(eta, np.asarray(y), ls=style, label=display_name(name))
    for ax, t in zip(axes.flat, titles):
        ax.set_title(t)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel(r"normalized time $\eta = t / t_f$")
    legend_below(fig)
    suptitle(fig, r"Motion laws ($t_f$ = 1, derivatives with respect to $\eta$)")
    return fig


def blends_overlay(curves: dict, corner=(0.0, 0.025)):
    """Fig. 6: blend curves (dict name -> (N, 2) points in the blend frame [m]) with the sharp corner."""
    fig, ax = plt.subplots(figsize=(COLUMN_WIDTH, 3.0), layout="constrained")
    cx, cy = 1e3 * np.asarray(corner)
    ax.plot([0, cx, cx + 30], [0, cy, cy], "k:", lw=1, label="Adept corner")
    for i, (name, pts) in enumerate(curves.items()):
        pts = np.asarray(pts) * 1e3
        family, _, rest = name.partition(" ")
        ax.plot(pts[:, 0], pts[:, 1], color=BLEND_COLOR.get(family), ls=LINE_STYLES[i % len(LINE_STYLES)],
                label=" ".join(filter(None, (display_name(family), rest))))
    ax.set_aspect("equal")
    ax.set_xlabel("x along the traverse [mm]")
    ax.set_ylabel("y along the lift [mm]")
    ax.set_title("Corner blends, d = e = 25 mm")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=LEGEND_SIZE, loc="lower right")
    return fig


def _panel_label(label: str, panel: str) -> str:
    """A curve's legend text in a panel: the part of ``label`` after the panel's own name ("lame-poly7"
    in the panel "lame": the law), else the whole label, readable."""
    for sep in ("-", "/"):
        if label.startswith(panel + sep):
            return display_name(label[len(panel) + 1:])
    return display_name(label)


def psd_panels(freqs, series: dict, title: str, ylabel: str = "PSD [(rad/s^2)^2/Hz]",
               panels: dict | None = None, fmin: float = 1.0, fmax: float | None = None):
    """Log-log PSD curves. ``series`` maps label -> (n_joints, F) PSD; one subplot per joint, or per
    group when ``panels`` maps panel title -> list of labels (joint 1 of each; a label that starts
    with its panel's title and "-" or "/" shows only the rest in the legend). The panels are laid
    out in at most two columns (one column wide for a single panel, ``PAGE_WIDTH`` otherwise); when
    every panel shows the same curves, one legend serves them all (in a free grid cell, else below)."""
    f = np.asarray(freqs)
    keep = f >= fmin if fmax is None else (f >= fmin) & (f <= fmax)
    if panels is None:
        n = np.asarray(next(iter(series.values()))).shape[0]
        content = [(f"joint {j + 1}", [(display_name(label), np.asarray(p)[j]) for label, p in series.items()])
                   for j in range(n)]
    else:
        content = [(display_name(ptitle), [(_panel_label(label, ptitle), np.asarray(series[label])[0])
                                           for label in labels]) for ptitle, labels in panels.items()]
    n = len(content)
    cols = 1 if n == 1 else 2
    rows = math.ceil(n / cols)
    shared = n > 1 and all([c[0] for c in curves] == [c[0] for c in content[0][1]] for _, curves in content)
    below = shared and rows * cols == n
    labels = [c[0] for c in content[0][1]]
    extra = 0.35 + 0.17 * math.ceil(len(labels) / legend_columns(labels, PAGE_WIDTH)) if below else 0.0
    fig, axes = plt.subplots(rows, cols, figsize=(COLUMN_WIDTH if cols == 1 else PAGE_WIDTH, 0.6 + 2.5 * rows + extra),
                             sharey=True, squeeze=False, layout="constrained")
    flat = axes.ravel()
    for i, (ax, (ptitle, curves)) in enumerate(zip(flat, content)):
        for k, (label, p) in enumerate(curves):
            ax.loglog(f[keep], p[keep], ls=LINE_STYLES[k % len(LINE_STYLES)], label=label, lw=1)
        ax.set_title(ptitle)
        ax.grid(alpha=0.3, which="both")
        if i + cols >= n:                       # no panel below this one
            ax.set_xlabel("frequency [Hz]")
        if i % cols == 0:
            ax.set_ylabel(ylabel)
        if not shared:
            ax.legend(fontsize=LEGEND_SIZE)
    for ax in flat[n:]:
        ax.axis("off")
    if shared:
        handles, labels = flat[0].get_legend_handles_labels()
        if below:
            legend_below(fig, handles, labels)
        else:
            flat[n].legend(handles, labels, loc="center", fontsize=LEGEND_SIZE, frameon=False)
    suptitle(fig, title)
    return fig


def lines(x, series: dict, xlabel: str, ylabel: str, title: str, logy: bool = False, styles=None):
    """Generic line plot of several series sharing x."""
    fig, ax = plt.subplots(figsize=(PAGE_WIDTH, 4.2), layout="constrained")
    for i, (label, y) in enumerate(series.items()):
        style = (styles or {}).get(label, LINE_STYLES[i % len(LINE_STYLES)])
        ax.plot(np.asarray(x), np.asarray(y), style, label=display_name(label), lw=1.2)
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=LEGEND_SIZE)
    return fig


def tracking_errors(t, t_dwell, e_norm: dict, e_dwell: dict, title: str):
    """Fig. 12: |e| [mm] over the motion (left) and |e - e_static| over the dwell (right), one line
    per 'blend/profile' key, one colour per profile and one line style per blend; two legends below
    the panels, the blends' line styles and the profiles' colours."""
    blends = list(dict.fromkeys(key.partition("/")[0] for key in e_norm))
    profiles = list(dict.fromkeys(key.partition("/")[2] for key in e_norm))
    styles = {b: LINE_STYLES[i % len(LINE_STYLES)] for i, b in enumerate(blends)}
    colors = {p: f"C{i % 10}" for i, p in enumerate(profiles)}
    rows = max(math.ceil(len(blends) / legend_columns([display_name(b) for b in blends], PAGE_WIDTH / 2)),
               math.ceil(len(profiles) / legend_columns([display_name(p) for p in profiles], PAGE_WIDTH / 2)))
    ncol = lambda entries: math.ceil(len(entries) / rows)            # both legends in as many rows
    fig, (a, b) = plt.subplots(1, 2, figsize=(PAGE_WIDTH, 3.4 + 0.17 * rows), layout="constrained")
    for key, v in e_norm.items():
        blend, _, prof = key.partition("/")
        a.plot(t, v, ls=styles[blend], color=colors[prof], lw=1, label=display_name(key))
        b.plot(t_dwell, e_dwell[key], ls=styles[blend], color=colors[prof], lw=1)
    a.set(xlabel="t [s]", ylabel="|e| [mm]", title="during the motion")
    b.set(xlabel="t [s]", ylabel="|e - e_static| [mm]", title="dwell at the place pose", yscale="log")
    names = [display_name(x) for x in blends]
    legend_below(fig, [Line2D([], [], color="0.25", ls=styles[x], lw=1.2) for x in blends], names,
                 title="blend (line style)", loc="outside lower left", ncol=ncol(blends))
    names = [display_name(x) for x in profiles]
    legend_below(fig, [Line2D([], [], color=colors[x], lw=1.5) for x in profiles], names,
                 title="motion law (colour)", loc="outside lower right", ncol=ncol(profiles))
    suptitle(fig, title)
    return fig
