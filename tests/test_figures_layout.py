"""Figures that misled (issue 33), checked on small synthetic inputs: no empty panel, no legend over a panel, no
promise of a truth line where there is no truth, and a run that did not converge says so in its title."""

from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

from neckstrength.abc.plots import abc_traces
from neckstrength.model.geometry import PLANE_GRID
from neckstrength.pipeline.postures import fig_postures
from neckstrength.plotting import PLANE_TITLES, radar_grid_series
from neckstrength.sequential.plots import fig_posteriors

matplotlib.use("Agg")
ROOT = Path(__file__).resolve().parents[1]


def _overlaps(fig) -> list[str]:
    """Legends whose box overlaps the box of a visible axes (its plotting area)."""
    fig.canvas.draw()
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    bad = []
    for leg in legends:
        lb = leg.get_window_extent()
        for ax in fig.axes:
            if ax.get_visible() and ax.axison and lb.overlaps(ax.get_window_extent()):
                bad.append(f"legend {[t.get_text() for t in leg.get_texts()][:3]} over panel '{ax.get_title()}'")
    return bad


@pytest.fixture(scope="module")
def directions():
    import os

    from neckstrength.config import build_directions, load_config

    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        return build_directions(load_config(ROOT / "config" / "config.ci.yaml"))
    finally:
        os.chdir(cwd)


def _history(params, iters=20, seed=1):
    rng = np.random.default_rng(seed)
    rows = []
    for p in params:
        for it in range(iters + 1):
            f = 200 + 50 * np.exp(-it / 5) + rng.normal(0, 3)
            rows.append({"parameter": p, "iteration": it, "f_c": f, "f_low": 0.8 * f, "f_high": 1.2 * f})
    return pd.DataFrame(rows)


def test_traces_of_a_participant_promise_no_truth_and_say_not_converged(tmp_path, figures):
    params = ["TC-E", "TC-F", "TS-B", "TS-E", "TS-F", "CS-E", "CS-F"]
    base = pd.Series(250.0, index=params)
    abc_traces(_history(params), pd.Series(np.nan, index=params), base, tmp_path / "p.png", "S003",
               converged=False, iterations=20, D_fc=0.51, eps_D=0.95)
    fig = figures[-1]
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert not any("true" in lb for lb in labels) and "participant" in fig.legends[0].get_title().get_text()
    assert "NOT CONVERGED" in fig._suptitle.get_text() and "0.510" in fig._suptitle.get_text()
    assert not _overlaps(fig)
    abc_traces(_history(params), pd.Series(210.0, index=params), base, tmp_path / "s.png", "norm",
               converged=True, iterations=6, D_fc=0.96, eps_D=0.95)
    fig = figures[-1]
    assert any("true strength" in t.get_text() for t in fig.legends[0].get_texts())
    assert fig._suptitle.get_text().endswith("converged after 6 iterations, D(f_c) = 0.960")
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_radar_of_a_planar_model_has_no_empty_panel(tmp_path, figures, directions):
    p2m7 = ["forehead", "noseBelow", "chinFront", "chinUnder", "backLow", "back", "backHigh"]
    vals = pd.Series(np.linspace(100, 300, 7), index=p2m7)
    radar_grid_series(directions, [("measured", vals, {"color": "blue"}), ("model", 0.9 * vals, {})],
                      tmp_path / "r.png", "fit", rlabel="N")
    fig = figures[-1]
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in shown] == ["mid sagittal"]
    assert "8 of the 9 planes" in fig._suptitle.get_text()
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["measured", "model"]   # not an empty box
    assert not _overlaps(fig)
    everywhere = pd.Series(150.0, index=directions["name"])
    radar_grid_series(directions, [("all", everywhere, {})], tmp_path / "a.png", "all")
    assert sum(ax.get_visible() for ax in figures[-1].axes) == sum(len(r) for r in PLANE_GRID) == 9
    with pytest.raises(ValueError, match="no series has a value"):
        radar_grid_series(directions, [("none", pd.Series(dtype=float), {})], tmp_path / "n.png")


def _drawn_panels(fig):
    """The visible axes of ``fig`` once drawn, each with the renderer that measures its text boxes."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    return [(ax, r) for ax in fig.axes if ax.get_visible()]


def _label_clashes(fig) -> list[str]:
    """Pairs of direction labels (theta tick labels) of one radar panel whose boxes overlap once drawn."""
    bad = []
    for ax, r in _drawn_panels(fig):
        labs = [t.label1 for t in ax.xaxis.get_major_ticks() if t.label1.get_visible() and t.label1.get_text()]
        boxes = [t.get_window_extent(r) for t in labs]
        bad += [f"{ax.get_title()}: {labs[i].get_text()!r} / {labs[j].get_text()!r}" for i in range(len(labs))
                for j in range(i + 1, len(labs)) if boxes[i].overlaps(boxes[j])]
    return bad


def test_radar_direction_labels_do_not_overlap(tmp_path, figures, directions):
    # directions that share (or nearly share) their angle in a plane, e.g. aboveEarR and earR in the right sagittal
    # plane, backUnderR and backLowR in the inferior transverse one, had their labels printed over each other
    vals = pd.Series(np.linspace(80, 300, len(directions)), index=directions["name"])
    radar_grid_series(directions, [("measured", vals, {"color": "blue"})], tmp_path / "r.png", "all", rlabel="N")
    fig = figures[-1]
    assert not _label_clashes(fig), _label_clashes(fig)
    for ax in fig.axes:                      # every direction of a panel is still named there
        text = " ".join(t.label1.get_text() for t in ax.xaxis.get_major_ticks())
        members = directions[directions["planes"].astype(str).str.split(";").apply(
            lambda ps, a=ax: any(PLANE_TITLES[p] == a.get_title() for p in ps))]["name"]
        assert all(n in text.replace("\n", " ").replace(" / ", " ").split() for n in members), ax.get_title()


def _radius_labels_over_lines(fig) -> list[str]:
    """Radius labels (y tick labels) of a radar panel whose drawn boxes a plotted line crosses (segments sampled in
    display coordinates)."""
    bad = []
    for ax, r in _drawn_panels(fig):
        pts = []
        for line in ax.lines:
            xy = ax.transData.transform(line.get_xydata())
            for p, q in zip(xy[:-1], xy[1:]):
                if np.isfinite(p).all() and np.isfinite(q).all():
                    pts.append(p + np.linspace(0, 1, 200)[:, None] * (q - p))
        pts = np.vstack(pts)
        for t in ax.yaxis.get_major_ticks():
            if t.label1.get_visible() and t.label1.get_text():
                b = t.label1.get_window_extent(r)
                if ((pts[:, 0] >= b.x0) & (pts[:, 0] <= b.x1) & (pts[:, 1] >= b.y0) & (pts[:, 1] <= b.y1)).any():
                    bad.append(f"{ax.get_title()}: {t.label1.get_text()}")
    return bad


def test_radar_radius_labels_clear_of_the_data(tmp_path, figures, directions):
    # the radius labels (50 ... 350) were drawn at one fixed angle from the centre out, over the traces that
    # enclose the centre (every gap radar): they go to each panel's emptiest sector, and any still over a line are
    # blanked, the scale kept readable by at least two labels per panel
    rng = np.random.default_rng(3)
    meas = pd.Series(rng.uniform(80, 300, len(directions)), index=directions["name"])
    model = meas * rng.uniform(0.6, 1.3, len(meas))
    radar_grid_series(directions, [("measured", meas, {"color": "blue", "ls": "--"}), ("model", model, {"lw": 2})],
                      tmp_path / "r.png", "fit", rlabel="N")
    fig = figures[-1]
    assert not _radius_labels_over_lines(fig), _radius_labels_over_lines(fig)
    for ax in fig.axes:
        shown = [t.label1.get_text() for t in ax.yaxis.get_major_ticks() if t.label1.get_text()]
        assert len(shown) >= 2, (ax.get_title(), shown)


def test_posteriors_legend_below_the_panels(tmp_path, figures):
    names = [f"m{i}" for i in range(8)]                    # a full grid: no free slot to hide a legend in
    f = np.linspace(0, 400, 41)
    post = pd.DataFrame([{"muscle": n, "iteration": t, "f": x, "density": np.exp(-((x - 200) / (90 - 10 * t)) ** 2)}
                         for n in names for t in range(4) for x in f])
    est = pd.DataFrame({"muscle": names, "f_actual": 210.0})
    fig_posteriors(post, est, tmp_path / "p.png", "Fig. 6.4a")
    fig = figures[-1]
    assert fig.legends and not _overlaps(fig)


def test_postures_legends_cover_no_bar(tmp_path, figures):
    groups = ["LC", "Lcap", "SCM", "mf", "trap"]
    summary = pd.DataFrame([{"t": t, "arm": arm, "group": g, "rel_error": 0.1 + 0.05 * k, "rel_sd": 0.2,
                             "n_tests": t} for t in (5, 10) for arm in ("neutral", "postures")
                            for k, g in enumerate(groups)])
    picks = pd.DataFrame([{"arm": "postures", "t": t, "posture": ["ext20", "flex20", "neutral"][(t + i) % 3]}
                          for t in range(1, 11) for i in range(4)])
    fig_postures(summary, pd.DataFrame(), picks, "p3m12", tmp_path / "f.png")
    fig = figures[-1]
    assert len(fig.legends) == 1 and not _overlaps(fig)
    assert "tests: neutral 10, postures 10" in fig.axes[1].get_title()


def test_png_figures_are_palette_images(tmp_path):
    """Figures are written as 256-colour PNGs (about a third of the RGBA bytes: the report embeds every one)."""
    from PIL import Image

    from neckstrength.plotting import save_png

    fig, ax = plt.subplots(figsize=(6, 4))
    x = np.linspace(0, 10, 200)
    for k in range(6):
        ax.plot(x, np.sin(x + k), label=f"line {k}")
    ax.set_xlabel("x")
    ax.legend()
    fig.savefig(tmp_path / "rgba.png", dpi=110)
    save_png(fig, tmp_path / "palette.png")
    plt.close(fig)
    rgba, pal = Image.open(tmp_path / "rgba.png"), Image.open(tmp_path / "palette.png")
    assert pal.mode == "P" and pal.size == rgba.size
    assert (tmp_path / "palette.png").stat().st_size < 0.6 * (tmp_path / "rgba.png").stat().st_size
    diff = np.abs(np.asarray(pal.convert("RGB"), float) - np.asarray(rgba.convert("RGB"), float))
    assert diff.mean() < 2.0                               # on a 0-255 scale: the same picture
