"""Shared plot helpers: the radar grid of the test directions by plane (Figs. A.4, 5.x, 6.x, gap) and saving.

Matplotlib with the non-interactive Agg backend (no display needed). Topic figures live in each subpackage's
``plots.py`` (``abc.plots``, ``surfaces.plots``, ``sequential.plots``, ``mfi.plots``) and ``gap.report``.
"""

from __future__ import annotations

import io
import textwrap
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from neckstrength.model.geometry import PLANE_GRID, plane_angle

matplotlib.use("Agg")


PLANE_TITLES = {
    "sagittal_right": "right sagittal", "sagittal_mid": "mid sagittal", "sagittal_left": "left sagittal",
    "transverse_superior": "superior transverse", "transverse_mid": "mid transverse",
    "transverse_inferior": "inferior transverse", "coronal_anterior": "anterior coronal",
    "coronal_mid": "mid coronal", "coronal_posterior": "posterior coronal",
}


def radar_grid(directions: pd.DataFrame, dashed: Mapping[str, pd.Series], solid: Mapping[str, pd.Series],
               out: str | Path, title: str = "", rmax: float | None = None) -> None:
    """Radar plots by plane (Fig. 4.2 layout): dashed traces (e.g. participants) and solid red traces."""
    series = [(k, v, {"ls": "--", "lw": 1}) for k, v in dashed.items()]
    series += [(k, v, {"ls": "-", "lw": 2, "color": "red"}) for k, v in solid.items()]
    radar_grid_series(directions, series, out, title, rmax)


def radar_grid_series(directions: pd.DataFrame, series: Sequence[tuple[str, pd.Series, dict]], out: str | Path,
                      title: str = "", rmax: float | None = None, rlabel: str = "") -> None:
    """Radar plots of the test directions, one polar axis per plane of Fig. 4.2 (3x3 when every plane has values).

    ``series``: (label, values indexed by direction name, matplotlib kwargs). Directions are placed at
    their polar angle within each plane (sagittal: x right / y up; transverse: x right / z up;
    coronal: z right / y up). A plane in which no series has values at 3 or more angles (a planar model's tests
    lie in the mid-sagittal plane; elsewhere they fall on one line) gets no panel, and the title says how many
    planes were left out; the legend sits below the panels, never over one. Directions at one angle of a plane share
    one label, and labels that would overlap once drawn are joined, so that every direction is named legibly. The
    radius labels (grey) run along each panel's emptiest sector, and those that a trace still crosses are left blank.
    """
    recs = directions.to_dict("records")
    panels = []
    for plane in (p for row in PLANE_GRID for p in row):
        members = [r for r in recs if plane in str(r["planes"]).split(";")]
        members.sort(key=lambda r: np.mod(plane_angle(r, plane), 2 * np.pi))
        names = [r["name"] for r in members]
        th = np.round(np.mod([plane_angle(r, plane) for r in members], 2 * np.pi), 3)
        for _, s, _ in series:
            ok = np.isfinite(np.array([s.get(n, np.nan) for n in names], float))
            if len(set(th[ok])) >= 3:                   # a polygon, not a line through the centre
                panels.append((plane, members, names))
                break
    if not panels:
        raise ValueError(f"radar plot {Path(out).name}: no series has a value in any test direction")
    ncol = 3 if len(panels) > 4 else min(len(panels), 2)
    nrow = int(np.ceil(len(panels) / ncol))
    width = max(4.0 * ncol, 6.5)
    fig, axes = plt.subplots(nrow, ncol, figsize=(width, 4 * nrow + 0.8), subplot_kw={"projection": "polar"},
                             squeeze=False)
    allvals = [np.nanmax(s.to_numpy(float)) for _, s, _ in series if np.isfinite(s.to_numpy(float)).any()]
    rmax = rmax or (1.1 * max(allvals) if allvals and max(allvals) > 0 else 1.0)
    for k, (plane, members, names) in enumerate(panels):
        ax = axes.ravel()[k]
        ax.set_title(PLANE_TITLES[plane], fontsize=10, pad=14)
        th = np.mod(np.array([plane_angle(r, plane) for r in members]), 2 * np.pi)
        closed = np.r_[th, th[:1]]
        for label, s, kw in series:
            vals = np.array([s.get(n, np.nan) for n in names], float)
            ax.plot(closed, np.r_[vals, vals[:1]], label=label, **kw)
        uth = np.unique(np.round(th, 3))          # one tick per angle: directions sharing it share a label
        ax.set_xticks(uth)
        ax.set_xticklabels([_joined([n for n, t in zip(names, np.round(th, 3)) if t == u], u) for u in uth],
                           fontsize=7)
        ax.set_xlim(0, 2 * np.pi)
        ax.set_ylim(0, rmax)
        ax.set_rlabel_position(np.rad2deg(_quietest_angle(th, [np.array([s.get(n, np.nan) for n in names], float)
                                                              for _, s, _ in series])))
        ax.tick_params(axis="y", labelsize=6, labelcolor="0.35")
        _align_labels(ax)
    for ax in axes.ravel()[len(panels):]:
        ax.set_visible(False)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 3 if ncol < 3 else 6), fontsize=8)
    omitted = 9 - len(panels)
    text = title + (f" [{rlabel}]" if rlabel else "")
    if omitted:
        text += f" ({omitted} of the 9 planes, with values at fewer than 3 angles, not shown)"
    if text:
        fig.suptitle(textwrap.fill(text, int(width * 11)), fontsize=11 if ncol == 3 else 10)
    legend_h = 0.35 * int(np.ceil(len(labels) / (3 if ncol < 3 else 6))) + 0.3 if handles else 0.2
    rect = (0, legend_h / (4 * nrow + 0.8), 1, 1)
    fig.tight_layout(rect=rect)
    for _ in range(3):                             # labels of nearby angles that overlap once drawn: joined
        if not sum(_join_overlapping_labels(ax) for ax in axes.ravel()[:len(panels)]):
            break
        fig.tight_layout(rect=rect)
    fig.canvas.draw()
    for ax in axes.ravel()[:len(panels)]:
        _hide_radius_labels_over_data(ax)
    _save(fig, out)


def _quietest_angle(th: np.ndarray, values: Sequence[np.ndarray], half_width: float = np.deg2rad(15)) -> float:
    """The angle (radians) of the radius labels: the middle of the sector (+- ``half_width``) in which the drawn
    lines (straight chords between the directions' points, closed, broken at missing values) come closest to the
    centre, so that the labels sit in the panel's emptiest sector; ties go to the angle nearest 250 degrees. Only
    angles at least 30 degrees off the horizontal are candidates, so that the labels, written horizontally along the
    ray, stack without running into each other."""
    pts = []
    t = np.linspace(0, 1, 41)[:, None]
    for v in values:
        x, y = v * np.cos(th), v * np.sin(th)
        a = np.c_[x, y]
        b = np.roll(a, -1, axis=0)
        ok = np.isfinite(a).all(1) & np.isfinite(b).all(1)
        for p, q in zip(a[ok], b[ok]):
            pts.append(p + t * (q - p))
    if not pts:
        return np.deg2rad(250)
    pts = np.vstack(pts)
    ang, rad = np.arctan2(pts[:, 1], pts[:, 0]), np.hypot(pts[:, 0], pts[:, 1])
    cand = np.deg2rad(np.arange(0, 360, 5))
    cand = cand[np.abs(np.sin(cand)) >= 0.5]       # steep enough that the labels (horizontal text) stack apart
    near = np.abs(np.angle(np.exp(1j * (ang[None, :] - cand[:, None])))) <= half_width
    reach = np.where(near, rad[None, :], 0).max(1)
    off = np.abs(np.angle(np.exp(1j * (cand - np.deg2rad(250)))))
    return float(cand[np.lexsort((off, np.round(reach, 9)))[0]])


def _radius_label_clashes(ax) -> list:
    """The radius (y) tick labels of a drawn polar ``ax`` whose boxes cross a plotted line."""
    from matplotlib.path import Path as MplPath

    r = ax.figure.canvas.get_renderer()
    paths = []
    for line in ax.lines:
        xy = line.get_xydata()
        ok = np.isfinite(xy).all(1)
        runs = np.split(np.arange(len(xy)), np.flatnonzero(np.diff(ok.astype(int))) + 1)
        paths += [line.get_transform().transform_path(MplPath(xy[i])) for i in runs if ok[i[0]] and len(i) > 1]
    return [t for t in ax.yaxis.get_major_ticks() if t.label1.get_visible() and t.label1.get_text()
            and any(p.intersects_bbox(t.label1.get_window_extent(r), filled=False) for p in paths)]


def _hide_radius_labels_over_data(ax) -> None:
    """Blank the radius labels of a drawn polar ``ax`` that sit over a plotted line (the grid circles stay), keeping
    at least the two outermost, on a light box, where fewer would be left."""
    bad = _radius_label_clashes(ax)
    if not bad:
        return
    lo, hi = ax.get_ylim()
    ticks = [t for t in ax.yaxis.get_major_ticks() if lo <= t.get_loc() <= hi]
    locs = [t.get_loc() for t in ticks]
    texts = [t.label1.get_text() if t.label1.get_visible() else "" for t in ticks]
    keep = [bool(x) and t not in bad for x, t in zip(texts, ticks)]
    boxed = []
    for i in range(len(ticks) - 1, -1, -1):        # the scale stays readable: at least two labels
        if sum(keep) >= 2:
            break
        if texts[i] and not keep[i]:
            keep[i] = True
            boxed.append(i)
    ax.set_yticks(locs, [x if k else "" for x, k in zip(texts, keep)])
    ax.set_ylim(lo, hi)
    for i in boxed:
        ax.yaxis.get_major_ticks()[i].label1.set_bbox({"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none",
                                                       "alpha": 0.8})


def _joined(names: Sequence[str], theta: float) -> str:
    """One label for the directions at (nearly) one angle: side by side near the top and bottom of a panel, stacked
    at its sides (where a wide label would run into the next panel)."""
    return (" / " if abs(np.sin(theta)) > 0.7 else "\n").join(names)


def _join_overlapping_labels(ax) -> int:
    """Join the direction labels of ``ax`` whose boxes overlap once drawn into one label at the middle one's tick (the
    others' ticks and grid lines stay, unlabelled). Returns how many labels were joined away."""
    r = ax.figure.canvas.get_renderer()
    ticks = [t for t in ax.xaxis.get_major_ticks() if t.label1.get_visible()]
    locs = np.array([t.get_loc() for t in ticks], float)
    texts = [t.label1.get_text() for t in ticks]
    boxes = [t.label1.get_window_extent(r).expanded(1.05, 1.4) if texts[i] else None for i, t in enumerate(ticks)]
    group = list(range(len(ticks)))               # union-find over overlapping boxes

    def root(i):
        while group[i] != i:
            i = group[i]
        return i

    for i in range(len(ticks)):
        for j in range(i + 1, len(ticks)):
            if boxes[i] is not None and boxes[j] is not None and boxes[i].overlaps(boxes[j]):
                group[root(j)] = root(i)
    joined = 0
    new = list(texts)
    for g in {root(i) for i in range(len(ticks))}:
        members = [i for i in range(len(ticks)) if root(i) == g and texts[i]]
        if len(members) < 2:
            continue
        members.sort(key=lambda i: locs[i])
        if locs[members[-1]] - locs[members[0]] > np.pi:    # a group across 0 / 2 pi: in order from its start
            cut = int(np.argmax(np.diff(locs[members]))) + 1
            members = members[cut:] + members[:cut]
        keep = members[len(members) // 2]
        for i in members:
            new[i] = ""
        new[keep] = _joined([n for i in members for n in texts[i].replace(" / ", "\n").split("\n")], locs[keep])
        joined += len(members) - 1
    if joined:
        ax.set_xticks(locs)
        ax.set_xticklabels(new, fontsize=7)
        _align_labels(ax)
    return joined


def _align_labels(ax) -> None:
    """Each direction label anchored on the side facing its tick (left-aligned on the right of the panel, and so on),
    so that a long label does not reach back over the outer circle."""
    for t in ax.xaxis.get_major_ticks():
        c, s = np.cos(t.get_loc()), np.sin(t.get_loc())
        t.label1.set_horizontalalignment("left" if c > 0.2 else "right" if c < -0.2 else "center")
        t.label1.set_verticalalignment("bottom" if s > 0.2 else "top" if s < -0.2 else "center")


def _save(fig, out, dpi: int = 110):
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    if str(out).lower().endswith(".png"):
        save_png(fig, out, dpi)
    else:
        fig.savefig(out, dpi=dpi)
    plt.close(fig)


def save_png(fig, out: str | Path, dpi: int = 110, **savefig_kw) -> None:
    """``fig`` as a PNG with a 256-colour palette (no dithering); ``savefig_kw`` go to ``fig.savefig`` (e.g.
    ``bbox_inches``).

    Line, bar and map figures look the same at about a third of the bytes of matplotlib's RGBA PNG, which keeps
    the Snakemake report (every figure embedded in one HTML file) small.
    """
    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, **savefig_kw)
    buf.seek(0)
    img = Image.open(buf).convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT,
                                                   dither=Image.Dither.NONE)
    img.save(out, format="PNG", optimize=True)


def heatmap(table: pd.DataFrame, out: str | Path, title: str, cbar_label: str) -> None:
    """Muscles x directions heat map with a diverging colour map centred at 0 (Fig. 4.5)."""
    v = np.nanmax(np.abs(table.to_numpy(float))) or 1.0
    fig, ax = plt.subplots(figsize=(13, 8))
    im = ax.imshow(table.to_numpy(float), cmap="RdBu_r", vmin=-v, vmax=v, aspect="auto")
    ax.set_xticks(range(table.shape[1]))
    ax.set_xticklabels(table.columns, rotation=75, fontsize=8)
    ax.set_yticks(range(table.shape[0]))
    ax.set_yticklabels(table.index, fontsize=8)
    fig.colorbar(im, ax=ax, label=cbar_label)
    ax.set_title(title)
    fig.tight_layout()
    _save(fig, out)
