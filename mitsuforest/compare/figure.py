"""compare.png: two clouds' vertical profiles, returns histograms, intensity and scan-angle
distributions and density maps, framed with matplotlib's object API (no pyplot, Agg)."""

from __future__ import annotations

import numpy as np

from ..write.atomic import atomic_path
from . import metrics as m
from .report import RETURN_NUMBERS, Description

DPI = 100
COLOURS = ("#1f5fa8", "#c8442b")      # A, B
MAP_PIXELS = 300                      # a density map's cells on its longer side, at least 1 m each
INTENSITY_TOP = 4.0                   # the intensity panel's right end at most (x the ground median)


def write_compare_figure(path, a: Description, b: Description) -> None:
    """Write the six panels of A against B to ``path`` (PNG, atomically)."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(17, 10), dpi=DPI, layout="constrained")
    axes = fig.subplots(2, 3)
    labels = [f"A: {a.cloud.name}", f"B: {b.cloud.name}"]
    _profiles(axes[0, 0], (a, b), labels)
    _returns(axes[0, 1], (a, b), labels)
    _intensity(axes[0, 2], (a, b), labels)
    for ax, d, label in zip(axes[1, :2], (a, b), labels):
        _density(fig, ax, d, label)
    _scan_angles(axes[1, 2], (a, b), labels)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)


def _profiles(ax, descriptions, labels) -> None:
    for d, label, colour in zip(descriptions, labels, COLOURS):
        edges, shares = m.vertical_profile(d.height)
        ax.stairs(shares * 100, np.append(edges, edges[-1] + 1), orientation="horizontal", color=colour,
                  lw=1.5, label=label, baseline=None)
    ax.set_xscale("log")
    ax.set(xlabel="share of the points per 1 m of height (%, log)", ylabel="height above the ground (m)",
           title="Vertical profile (all returns)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def _returns(ax, descriptions, labels) -> None:
    k = max(len(d.pulses) for d in descriptions)
    n = np.arange(1, k)
    for i, (d, label, colour) in enumerate(zip(descriptions, labels, COLOURS)):
        share = m.shares(np.pad(d.pulses, (0, k - len(d.pulses))))[1:] * 100
        ax.bar(n + (i - 0.5) * 0.4, share, width=0.4, color=colour, label=label)
    ax.set_xticks(n)
    ax.set(xlabel="returns per pulse", ylabel="share of the pulses (%)", title="Returns histogram")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)


def _intensity(ax, descriptions, labels) -> None:
    present = [d.intensity for d in descriptions if d.intensity is not None]
    if not present:
        ax.text(0.5, 0.5, "no intensity", ha="center", va="center", transform=ax.transAxes)
    else:
        top = min(max(float(np.percentile(v, 99)) for v in present), INTENSITY_TOP)
        bins = np.linspace(0, max(top, 1e-9), 60)
        for d, label, colour in zip(descriptions, labels, COLOURS):
            if d.intensity is None:
                continue
            for r, style in zip(RETURN_NUMBERS, ("-", "--", ":")):
                values = d.intensity[d.cloud.return_number == r]
                if len(values):
                    ax.hist(values, bins, density=True, histtype="step", ls=style, color=colour, lw=1.3,
                            label=f"{label.split(':')[0]} return {r} ({len(values):,})")
        ax.legend(fontsize=8)
    ax.set(xlabel="intensity / median intensity of first-return ground echoes", ylabel="density",
           title="Intensity by return number")
    ax.grid(alpha=0.3)


def _density(fig, ax, d: Description, label: str) -> None:
    x, y = d.cloud.x, d.cloud.y
    x0, y0 = m.grid_origin(x, y)
    w, h = max(np.max(x) - x0, 1.0), max(np.max(y) - y0, 1.0)
    cell = max(1.0, max(w, h) / MAP_PIXELS)
    bins = [np.arange(0, w + cell, cell), np.arange(0, h + cell, cell)]
    counts, _, _ = np.histogram2d(x - x0, y - y0, bins)
    image = np.ma.masked_equal(counts.T / cell**2, 0)
    shown = ax.imshow(image, origin="lower", extent=(0, bins[0][-1], 0, bins[1][-1]), cmap="viridis",
                      interpolation="nearest")
    fig.colorbar(shown, ax=ax, label="points per m²", shrink=0.85)
    ax.set(xlabel=_offset_label("x", x0), ylabel=_offset_label("y", y0),
           title=f"Density, {label} ({cell:g} m cells; blank: no point)")


def _offset_label(axis: str, origin: float) -> str:
    return f"{axis} − {origin:.0f} (m)" if origin else f"{axis} (m)"


def _scan_angles(ax, descriptions, labels) -> None:
    shown = False
    for d, label, colour in zip(descriptions, labels, COLOURS):
        if d.cloud.scan_angle is None:
            continue
        ax.hist(d.cloud.scan_angle, np.arange(-90, 92, 2), density=True, histtype="step", color=colour, lw=1.5,
                label=label)
        shown = True
    if shown:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no scan angles", ha="center", va="center", transform=ax.transAxes)
    ax.set(xlabel="scan angle (°)", ylabel="density (per °)", title="Scan angles")
    ax.grid(alpha=0.3)
