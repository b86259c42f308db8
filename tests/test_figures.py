"""Figures fit for a paper: readable names instead of code names in legends and titles
(``jaxflex.names.display_name``), legends at 8 pt or more, figures at most 7.5 in wide (one or two
columns of a paper, so that nothing shrinks when they are placed), curves that differ in more than
colour, and a vector (SVG) copy beside every PNG (``experiments.io.save_figure``).

Fast: every figure is drawn from small made-up arrays of the shapes its function documents (the
optimize figures from stand-ins of the study object they read), never from a simulation; the
figures that call ``save_figure`` are caught before they are written (``capture``)."""
import re
from types import SimpleNamespace

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.text import Text

from jaxflex import plotting
from jaxflex.experiments import closed_loop as closed_loop_exp
from jaxflex.experiments import io as exp_io
from jaxflex.experiments import modes as modes_exp
from jaxflex.experiments import optimize as optimize_exp
from jaxflex.names import ALL_BLENDS, PROFILES, display_name
from jaxflex.uncertainty import ModelId

MAX_WIDTH = 7.5           # [in]: two columns of a paper (7.2 in) and a little slack
MIN_LEGEND = 8.0          # [pt]
MIN_TEXT = 8.0            # [pt]: ticks, labels, titles
# code names that must not be drawn (case-sensitive: "Ruckig", "Lamé" and "polar polynomial" are fine)
CODE_NAME = re.compile(r"\b(lame|poly7|bang_bang|trap_1_4|trap_1_8|polar_g3|polar_g4|ruckig)\b"
                       r"|\b(lame|clothoid|polar|smoothstep)[/-]")
RNG = np.random.default_rng(0)
BEST = "polar/trap_1_4 (best paper)"
CANDIDATES = (BEST, "polar/trap_1_4+ZV", "polar/trap_1_4+ZVD", "polar/ruckig", "optimized")


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


# --- the checks --------------------------------------------------------------------------------

def legends(fig) -> list:
    """Every legend of the figure: the figure's own and its axes'."""
    return list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]


def legend_texts(fig) -> list:
    """Every text of every legend (entries and titles) that shows something."""
    out = []
    for leg in legends(fig):
        out += [t for t in leg.get_texts() + [leg.get_title()] if t.get_text() and t.get_visible()]
    return out


def title_texts(fig) -> list:
    """The figure's title and its axes' titles that show something."""
    titles = [fig._suptitle] if fig._suptitle is not None else []
    for ax in fig.axes:
        titles += [ax.title, ax._left_title, ax._right_title]
    return [t for t in titles if t.get_text()]


def problems(fig) -> list:
    """What keeps the figure out of a paper: code names in legends or titles, legend text under
    MIN_LEGEND pt, any text under MIN_TEXT pt, a width (set or drawn, the tight box the files are
    saved with) over MAX_WIDTH."""
    fig.canvas.draw()                   # the ticks and their labels exist once drawn
    out = []
    for t in legend_texts(fig) + title_texts(fig):
        if CODE_NAME.search(t.get_text()):
            out.append(f"code name in {t.get_text()!r}")
    for t in legend_texts(fig):
        if t.get_fontsize() < MIN_LEGEND:
            out.append(f"legend text {t.get_text()!r} at {t.get_fontsize():g} pt")
    for t in fig.findobj(Text):
        if t.get_text().strip() and t.get_visible() and t.get_fontsize() < MIN_TEXT:
            out.append(f"text {t.get_text()!r} at {t.get_fontsize():g} pt")
    if fig.get_figwidth() > MAX_WIDTH:
        out.append(f"figure {fig.get_figwidth():g} in wide")
    drawn = fig.get_tightbbox(fig.canvas.get_renderer()).width
    if drawn > MAX_WIDTH:
        out.append(f"drawn {drawn:.2f} in wide")
    return out


def test_the_checks_catch_small_legends_code_names_and_wide_figures():
    """The checks can fail: a 16 in wide figure with a 6 pt legend that shows "lame/trap_1_4" and
    6 pt ticks is reported on all four counts (a check that passed everything would prove nothing
    about the figures below)."""
    fig, ax = plt.subplots(figsize=(16, 4))
    ax.plot([0, 1], [0, 1], label="lame/trap_1_4")
    ax.legend(fontsize=6)
    ax.tick_params(labelsize=6)
    found = " | ".join(problems(fig))
    assert "code name in 'lame/trap_1_4'" in found
    assert "legend text 'lame/trap_1_4' at 6 pt" in found
    assert "figure 16 in wide" in found and "drawn" in found
    assert re.search(r"text '0\.\d' at 6 pt", found)
    for raw in ("trap_1_8", "poly7", "clothoid/poly7", "polar-bang_bang", "ruckig"):
        assert CODE_NAME.search(raw), raw
    for shown in ("Lamé", "polar polynomial", "clothoid pair", "Ruckig (jerk-limited)", "smoothstep"):
        assert not CODE_NAME.search(shown), shown


# --- display names -----------------------------------------------------------------------------

@pytest.mark.parametrize("key, shown", [
    ("lame", "Lamé"), ("clothoid", "clothoid pair"), ("polar", "polar polynomial"), ("smoothstep", "smoothstep"),
    ("polar_g3", "polar (G3)"), ("polar_g4", "polar (G4)"),
    ("poly7", "7th-degree polynomial"), ("bang_bang", "bang-bang"), ("trap_1_4", "trapezoidal 1/4"),
    ("trap_1_8", "trapezoidal 1/8"), ("ruckig", "Ruckig (jerk-limited)"), ("shaped", "shaped"),
    ("optimized", "optimized")])
def test_display_name_of_each_blend_and_law(key, shown):
    """Every blend family and motion law a figure shows has its readable name, exactly (the names
    the paper's text uses; a changed name changes every figure)."""
    assert display_name(key) == shown


@pytest.mark.parametrize("key, shown", [
    ("lame/trap_1_4", "Lamé, trapezoidal 1/4"),
    ("lame/trap_1_4+ZV", "Lamé, trapezoidal 1/4 + ZV"),
    ("lame/trap_1_4+ZVD", "Lamé, trapezoidal 1/4 + ZVD"),
    ("polar/poly7 (best paper)", "polar polynomial, 7th-degree polynomial (best paper)"),
    ("clothoid/bang_bang", "clothoid pair, bang-bang"),
    ("polar/ruckig", "polar polynomial, Ruckig (jerk-limited)"),
    ("polar_g3/poly7+ZVD", "polar (G3), 7th-degree polynomial + ZVD"),
    ("lame-poly7", "Lamé, 7th-degree polynomial"),                 # the spectra's labels
    ("trap_1_8 (best paper)", "trapezoidal 1/8 (best paper)"),
    ("poly7+ZV", "7th-degree polynomial + ZV")])
def test_display_name_of_combination_labels(key, shown):
    """The combination labels the studies use as keys ("blend/law", with a shaper and the best
    paper suffix) read as "blend, law": the optimize and vibration figures' legends."""
    assert display_name(key) == shown


@pytest.mark.parametrize("key", ["optimized, rigid feedforward", "tf = 0.5 s", "foo/bar", "lame/foo",
                                 "6 kg", "", "poly7-Lamé", "Adept corner"])
def test_display_name_leaves_other_text_alone(key):
    """Text that is not a code name (free labels, unknown names, an unknown law after a known
    blend) passes through unchanged: the function can be applied to any legend label."""
    assert display_name(key) == key


def test_every_name_the_library_offers_has_a_display_name():
    """No blend family or paper law of ``jaxflex.names`` would reach a figure as a code name."""
    for key in ALL_BLENDS + PROFILES:
        assert not CODE_NAME.search(display_name(key)), key


# --- the library's figures (jaxflex.plotting) --------------------------------------------------

def _laws():
    """eta (N,) and law name -> (S, S', S'', S\'\'\') of arrays (N,), as ``motion_laws`` takes them."""
    eta = np.linspace(0.0, 1.0, 101)
    return eta, {p: (eta ** k, k * eta, np.sin(k * eta), np.cos(k * eta)) for k, p in enumerate(PROFILES, 1)}


def _psd(labels, joints=2, f=257):
    return {k: RNG.random((joints, f)) + 1e-6 for k in labels}


def library_figures() -> dict:
    """Every figure of ``jaxflex.plotting``, from made-up arrays of the documented shapes."""
    eta, laws = _laws()
    u = np.linspace(0.0, 1.0, 40)
    curves = {b: np.c_[0.025 * np.sin(np.pi / 2 * u), 0.025 * (1 - np.cos(np.pi / 2 * u))]
              for b in ("lame", "clothoid", "polar")}
    freqs = np.linspace(0.0, 5000.0, 257)
    combos = [f"{b}-{p}" for b in ("lame", "clothoid", "polar") for p in PROFILES]
    keys = [f"{b}/{p}" for b in ("lame", "clothoid", "polar") for p in PROFILES]
    t, td = np.linspace(0.0, 0.43, 60), np.linspace(0.0, 0.1, 30)
    return {
        "motion_laws": plotting.motion_laws(eta, laws),
        "blends_overlay": plotting.blends_overlay(curves),
        "psd_combinations (Fig. 8)": plotting.psd_panels(
            freqs, _psd(combos), "PSD of joint-1 acceleration, tf = 1 s (Fig. 8)",
            panels={b: [f"{b}-{p}" for p in PROFILES] for b in ("lame", "clothoid", "polar")}, fmax=2000),
        "psd_joints": plotting.psd_panels(freqs, _psd(combos[:4]), "both joints"),
        "psd_one_joint (Fig. 10)": plotting.psd_panels(
            freqs, _psd([f"tf = {x:g} s" for x in (1.0, 0.5, 0.25)], joints=1),
            "Lamé, 7th-degree polynomial, joint 1: cycle time (Fig. 10)", fmax=2000),
        "lines": plotting.lines(t, {k: RNG.random(60) for k in keys[:4]}, "t [s]", "y", "lines"),
        "tracking_errors (Fig. 12)": plotting.tracking_errors(
            t, td, {k: RNG.random(60) for k in keys}, {k: RNG.random(30) + 1e-3 for k in keys},
            "Fig. 12: end-effector error, 6 kg, tf = 0.43 s"),
    }


def test_library_figures_are_fit_for_a_paper():
    """Every ``jaxflex.plotting`` figure: readable names in its legends and titles, legends at
    8 pt or more, no text under 8 pt, at most 7.5 in wide (the PSD panels were 16 in wide in a
    row; Fig. 12's legend was at 6 pt and listed "lame/trap_1_4")."""
    found = {name: problems(fig) for name, fig in library_figures().items()}
    assert not any(found.values()), {k: v for k, v in found.items() if v}


def test_library_figures_show_the_readable_names():
    """The names are not only free of code names but are the display names: the Fig. 8 panels are
    titled by blend and list the laws; Fig. 12's legends list blends and laws."""
    figs = library_figures()
    fig8 = figs["psd_combinations (Fig. 8)"]
    assert [ax.get_title() for ax in fig8.axes[:3]] == ["Lamé", "clothoid pair", "polar polynomial"]
    assert [t.get_text() for t in legend_texts(fig8)] == [display_name(p) for p in PROFILES]
    fig12 = [t.get_text() for t in legend_texts(figs["tracking_errors (Fig. 12)"])]
    assert {"Lamé", "clothoid pair", "polar polynomial", "trapezoidal 1/4", "7th-degree polynomial"} <= set(fig12)
    assert [t.get_text() for t in legend_texts(figs["motion_laws"])] == [display_name(p) for p in PROFILES]


def test_psd_panels_are_laid_out_in_two_columns():
    """Three panels take a 2 x 2 grid (the fourth cell holds the shared legend), not a row of
    three 5 in panels: the spectra stay legible at two-column width."""
    fig = library_figures()["psd_combinations (Fig. 8)"]
    boxes = [ax.get_position() for ax in fig.axes[:3]]
    assert len({round(b.x0, 3) for b in boxes}) == 2 and len({round(b.y0, 3) for b in boxes}) == 2
    assert fig.get_figwidth() <= MAX_WIDTH and not fig.axes[3].axison


# --- the experiments' figures ------------------------------------------------------------------

@pytest.fixture
def capture(monkeypatch):
    """The figures the experiments would save, caught instead (path name -> figure)."""
    caught = {}

    def keep(fig, path, *args, **kwargs):
        caught[getattr(path, "name", str(path))] = fig

    monkeypatch.setattr(optimize_exp, "save_figure", keep)
    return caught


def _series(n_t=80, n_d=40, k=1, overlap=None):
    """A stand-in of ``study.series(name)``: t (K, T), e (K, T, 2), t_dwell (K, Td), e_dwell (K, Td, 2),
    e_static (K, 2) [m]."""
    e_dwell = overlap if overlap is not None else RNG.normal(size=(k, n_d, 2)) * 1e-5
    return SimpleNamespace(t=np.tile(np.linspace(0.0, 0.43, n_t), (k, 1)), e=RNG.normal(size=(k, n_t, 2)) * 1e-4,
                           t_dwell=np.tile(np.linspace(0.43, 0.53, n_d), (k, 1)), e_dwell=e_dwell,
                           e_static=np.zeros((k, 2)))


def _error_study():
    same = RNG.normal(size=(1, 40, 2)) * 1e-5         # ZVD and Ruckig on top of each other, as in the study
    series = {name: _series(overlap=same if name in ("polar/trap_1_4+ZVD", "polar/ruckig") else None)
              for name in CANDIDATES}
    return SimpleNamespace(candidates={name: None for name in CANDIDATES}, series=series.__getitem__,
                           payloads=(6.0,), tf=0.43)


def test_error_figure_tells_every_curve_apart(capture, tmp_path):
    """The error series (``error_figure``): ZVD and Ruckig lie on top of each other in the dwell,
    so every curve differs from every other in line style or marker, not in colour alone, in both
    panels (legible in grayscale and where curves overlap); and the figure passes the paper
    checks."""
    optimize_exp.error_figure(_error_study(), tmp_path / "error_series.png")
    fig = capture["error_series.png"]
    assert not problems(fig)
    for ax in fig.axes:
        shapes = [(line.get_linestyle(), line.get_marker()) for line in ax.get_lines()]
        assert len(shapes) == len(CANDIDATES)
        assert len(set(shapes)) == len(shapes), shapes           # distinct without colour
    names = [t.get_text() for t in legend_texts(fig)]
    assert names == [display_name(n) for n in CANDIDATES]
    assert "polar polynomial, trapezoidal 1/4 + ZVD" in names and "polar polynomial, Ruckig (jerk-limited)" in names


def _design_study():
    import jax.numpy as jnp

    from jaxflex.path import make_path
    from jaxflex.profiles import shaped
    from jaxflex.robot import cycle_preset

    cycle = cycle_preset()
    law = shaped(jnp.asarray([1.0, 0.6, 0.9]), 3, name="optimized")
    return SimpleNamespace(best_paper="trap_1_4", blend="polar", design=object(),
                           candidates={"optimized": SimpleNamespace(law=law)},
                           paths={"paper": make_path(cycle, "polar", 0.025), "optimized": make_path(cycle, "lame", 0.02)})


def test_optimized_law_figure_is_fit_for_a_paper(capture, tmp_path):
    """The design figure (``figure``): two-column width, its legends readable ("trapezoidal 1/4
    (best paper)", "polar polynomial, d = e = 25 mm (best paper)"), no code names, legends at 8 pt
    or more (it was a 15 in row of three panels)."""
    optimize_exp.figure(_design_study(), tmp_path)
    fig = capture["optimized_law.png"]
    assert not problems(fig)
    names = [t.get_text() for t in legend_texts(fig)]
    assert "trapezoidal 1/4 (best paper)" in names and "7th-degree polynomial" in names
    assert "polar polynomial, d = e = 25 mm (best paper)" in names and "optimized (Lamé)" in names
    # when the best paper law is poly7 itself, it is drawn and named once
    capture.clear()
    optimize_exp.figure(SimpleNamespace(**{**vars(_design_study()), "best_paper": "poly7"}), tmp_path)
    names = [t.get_text() for t in legend_texts(capture["optimized_law.png"])]
    assert names.count("7th-degree polynomial (best paper)") == 1 and "7th-degree polynomial" not in names


def test_box_figure_is_fit_for_a_paper(capture, monkeypatch, tmp_path):
    """The uncertainty-box figure (``box_figure``; the models' frequencies made up): one column
    per payload at most two columns wide, readable names, its legend (at 7 pt before) at 8 pt."""
    import jaxflex.model_sets

    ids = [ModelId(m, stiffness_scale=s) for m in (0.1, 6.0) for s in (0.9, 1.0, 1.1)]
    monkeypatch.setattr(optimize_exp, "build_model", lambda which, *args: which)
    monkeypatch.setattr(jaxflex.model_sets, "place_first_mode_hz", lambda model, cycle: 50.0 * model.stiffness_scale)
    study = SimpleNamespace(paths={"paper": SimpleNamespace(cycle=None)}, sets={"box": ids}, payloads=(0.1, 6.0),
                            tf=0.43, evaluations={"box": {name: {"dwell_residual_mm": RNG.random(len(ids)) * 1e-3}
                                                          for name in CANDIDATES}})
    optimize_exp.box_figure(study, None, tmp_path / "box_residuals.png")
    fig = capture["box_residuals.png"]
    assert not problems(fig)
    assert [t.get_text() for t in legend_texts(fig)] == [display_name(n) for n in CANDIDATES]


def test_cycle_time_figure_is_fit_for_a_paper(capture, tmp_path):
    """The Pareto figure (``cycle_time_figure``): one column wide, legend at 8 pt or more."""
    rows = [{"tf": tf, "paper_best_mm": 1e-2 / tf, "optimized_mm": 1e-3 / tf, "optimized_perturbed_worst_mm": 2e-3 / tf}
            for tf in (0.43, 0.40, 0.37)]
    optimize_exp.cycle_time_figure({"rows": rows, "tf_ref": 0.43, "payload": 6.0, "target_mm": 0.02,
                                    "target_perturbed_worst_mm": 0.03}, tmp_path / "cycle_time.png")
    fig = capture["cycle_time.png"]
    assert not problems(fig) and fig.get_figwidth() <= 4.0


def test_closed_loop_figure_is_fit_for_a_paper():
    """The residual-against-bandwidth figure (``experiments.closed_loop.figure``): readable names
    ("polar polynomial, 7th-degree polynomial"), one column wide, legend at 8 pt or more; still
    one line per trajectory and one per perfect-controller value."""
    row = {"perfect_um": 0.5}
    closed = {"fcs": {"40": {"optimized": row, "polar/poly7 (best paper)": row, "lame/poly7": row}}}
    sweep = {"fcs": [15.0, 40.0], "dwell_residual_um": {"optimized": [1.3, 0.25], "optimized, rigid feedforward": [2, 1],
                                                       "polar/poly7": [9.5, 1.08], "lame/poly7": [9.0, 2.0]}}
    fig = closed_loop_exp.figure(sweep, closed, "6 kg, 0.43 s")
    assert not problems(fig)
    assert len(fig.axes[0].get_lines()) == 4 + 3
    assert [t.get_text() for t in legend_texts(fig)] == [
        "optimized", "optimized, rigid feedforward", "polar polynomial, 7th-degree polynomial",
        "Lamé, 7th-degree polynomial"]


def test_modes_figure_is_fit_for_a_paper():
    """The natural-frequency figure (``experiments.modes.figure``, 13 in wide before): two columns
    wide, one legend of the payloads at 8 pt or more."""
    results = [{"payload": m, "points": [{"s": s, "freqs_hz": [50 + s + m, 90 + m, 130 - m]}
                                         for s in np.linspace(0.0, 0.4, 6)]} for m in (0.1, 6.0)]
    fig = modes_exp.figure(results)
    assert not problems(fig)
    assert [t.get_text() for t in legend_texts(fig)] == ["0.1 kg", "6 kg", "payload"]


# --- save_figure --------------------------------------------------------------------------------

def test_save_figure_writes_a_png_and_an_svg_beside_it(tmp_path):
    """``save_figure`` writes the PNG (at 200 dpi: a 3.5 in figure is about 700 pixels wide) and a
    vector copy with the same stem and ``.svg`` (a paper's figure scales without loss), both
    atomically (no temporary files left), the SVG without a creation date (the same figure, the
    same file), and closes the figure."""
    fig, ax = plt.subplots(figsize=(3.5, 2.5))
    ax.plot([0, 1], [1, 0], label="Lamé")
    ax.legend(fontsize=8)
    exp_io.save_figure(fig, tmp_path / "sub" / "f.png")
    files = sorted(p.name for p in (tmp_path / "sub").iterdir())
    assert files == ["f.png", "f.svg"]
    width = matplotlib.image.imread(tmp_path / "sub" / "f.png").shape[1]
    assert 0.8 * 3.5 * 200 < width <= 3.6 * 200
    svg = (tmp_path / "sub" / "f.svg").read_text()
    assert svg.lstrip().startswith("<?xml") and "<svg" in svg and "<dc:date>" not in svg
    assert not plt.fignum_exists(fig.number)


def test_save_figure_of_a_vector_path_writes_that_file_only(tmp_path):
    """A path that already names a vector format (``.svg``, ``.pdf``) gets that file alone: the
    copy is for PNGs."""
    for name in ("g.svg", "h.pdf"):
        fig, ax = plt.subplots(figsize=(3.5, 2.5))
        ax.plot([0, 1], [1, 0])
        exp_io.save_figure(fig, tmp_path / name)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.svg", "h.pdf"]
