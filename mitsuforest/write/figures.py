"""The render's pictures and charts, framed with matplotlib (axes in metres, legends of class names).

The point rasters come from ``quicklook.py`` (numpy); matplotlib only frames them, so a picture costs
the same for a thousand points or forty million. Figures are made with the object API
(:class:`~matplotlib.figure.Figure`), never pyplot, so nothing global changes and threads are safe.
"""

from __future__ import annotations

import functools

import numpy as np

from ..classes import TREE_LEAVES, TREE_WOOD, class_name
from .atomic import atomic_path
from .quicklook import CLASS_COLOURS, WOODY_CLASSES, front_points, instance_palette, paint

DPI = 100
PNG_LEVEL = 3      # zlib level of the pictures
_WOODY = np.isin(np.arange(256), WOODY_CLASSES)          # by class code
_TREE = np.isin(np.arange(256), (TREE_WOOD, TREE_LEAVES))
NON_TREE_GREY = 200
MIN_AXES_IN = 3.9     # inches: the narrowest axes box of a top view, half of it the half-width of its title
MAX_TILE_HEIGHT_IN = 12.0   # inches: the side view's panels at most (a 1 m tile of 30 m trees would be 108)
LEGEND_DROP_IN = 0.5   # inches from an axes' bottom edge down to a legend under it: clear of tick labels and x label


def _figure(width_in: float, height_in: float, left: float, right: float, bottom: float, top: float,
            between: float = 0.0):
    """A figure whose axes keep fixed margins, in inches (room for tick labels, titles and legends
    outside the axes): half the drawing time of matplotlib's constrained layout, which measures every
    text each time."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(width_in, height_in), dpi=DPI)
    fig.subplots_adjust(left=left / width_in, right=1 - right / width_in, bottom=bottom / height_in,
                        top=1 - top / height_in, wspace=between)
    return fig


def _save(fig, path) -> None:
    """Draw ``fig`` once and write it as an RGB PNG: the pixels ``fig.savefig(path, dpi=DPI)`` writes (its
    RGBA at zlib level 6 takes 1.4 times as long to compress, for files 5 % smaller)."""
    from PIL import Image
    canvas = _canvas_class()(fig)
    canvas.draw()
    rgb = np.ascontiguousarray(np.asarray(canvas.buffer_rgba())[..., :3])    # the figures are opaque
    with atomic_path(path) as tmp:
        # The margins of _figure already make room for legends outside the axes (no bbox_inches="tight").
        Image.fromarray(rgb).save(tmp, format="PNG", dpi=(DPI, DPI), compress_level=PNG_LEVEL)


def warm_up() -> None:
    """Take a small figure through every step a picture takes (matplotlib's imports, its fonts, the
    mathtext of log-axis tick labels, the PNG encoder; scipy's ``ndimage`` for the top view), writing
    nothing: in a process that has drawn none, the first picture costs 0.3–0.4 s more than the next."""
    import io

    import scipy.ndimage  # noqa: F401  (TopView.image's; 0.28 s to import)
    from PIL import Image
    from matplotlib.patches import Patch
    fig = _figure(2.0, 2.0, left=0.5, right=0.1, bottom=0.4, top=0.3)
    image, chart = fig.subplots(1, 2)
    image.imshow(np.zeros((4, 4, 3), np.uint8), extent=(0, 1, 0, 1), interpolation="nearest")
    image.annotate("tile", (0, 0), xytext=(2, 3), textcoords="offset points", fontsize=8)
    chart.stairs([1, 10, 100], [0, 1, 2, 3], orientation="horizontal")
    _log_scale(chart, "x")
    _title(chart, "warm-up")
    chart.legend(handles=[Patch(color="black", label="class")], fontsize=8)
    canvas = _canvas_class()(fig)
    canvas.draw()
    Image.fromarray(np.asarray(canvas.buffer_rgba())[..., :3].copy()).save(io.BytesIO(), format="PNG",
                                                                          compress_level=PNG_LEVEL)


def _title(ax, text: str, **kwargs) -> None:
    """Give ``ax`` a title at a fixed height. Left to place itself, a title measures every tick label of
    its axes at each draw to clear ticks on top, which no axes here has (a fifth of the drawing, by
    cProfile)."""
    ax.set_title(text, y=1.0, **kwargs)


def _log_scale(ax, axis: str) -> None:
    """Put ``ax``'s ``axis`` ("x" or "y") on a log scale with ticks at the decades only: the eight minor
    ticks of each decade were half the drawing time of a chart."""
    ax.set(**{f"{axis}scale": "log"})
    ax.minorticks_off()


@functools.cache
def _canvas_class():
    """An Agg canvas whose renderers share the process's one mathtext parser: the log axes' tick labels
    (``$10^{3}$``) are parsed once, not once a picture (each renderer had a parser, and its cache, of
    its own)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.mathtext import MathTextParser
    parser = MathTextParser("path")     # what RendererAgg makes; its cache is thread-safe

    class Canvas(FigureCanvasAgg):
        def get_renderer(self):
            renderer = super().get_renderer()
            renderer.mathtext_parser = parser
            return renderer

    return Canvas


def _class_legend(ax, codes, **kwargs) -> None:
    from matplotlib.patches import Patch
    handles = [Patch(color=CLASS_COLOURS[c] / 255, label=class_name(c)) for c in codes]
    ax.legend(handles=handles, fontsize=8, framealpha=0.9, **kwargs)


def _below(ax) -> dict:
    """A legend's placement under ``ax``, a fixed distance below its bottom edge whatever the axes' height
    (a fraction of the height put it over the x label of a short tile)."""
    from matplotlib.transforms import ScaledTranslation
    return dict(loc="upper center", bbox_to_anchor=(0.5, 0.0),
                bbox_transform=ax.transAxes + ScaledTranslation(0, -LEGEND_DROP_IN, ax.figure.dpi_scale_trans))


def write_top_figure(path, top, tile=None, classes_present=()) -> None:
    """Write :func:`top_figure` to ``path``."""
    _save(top_figure(top, tile, classes_present), path)


def top_figure(top, tile=None, classes_present=()):
    """The plot from above, each pixel the class of its highest point, metre axes, the tile outlined.

    :param top: a :class:`~.quicklook.TopView`; ``tile`` a :class:`~.quicklook.SideTile`.
    """
    from matplotlib.patches import Rectangle
    w, h = top.area
    side = 7.0
    left, right = 0.7, 1.75
    width = max(side * min(w / h, 1.6) + 1.8, left + right + MIN_AXES_IN)    # a narrow plot keeps room for its title
    fig = _figure(width, side, left=left, right=right, bottom=0.6, top=0.5)
    ax = fig.add_subplot()
    ax.imshow(top.image(), extent=(0, w, 0, h), interpolation="nearest")
    if tile is not None:
        ax.add_patch(Rectangle((tile.x0, tile.y0), tile.tile, tile.tile, fill=False, lw=1.2, ec="black", ls="--"))
        ax.annotate(f"{tile.tile:g} m tile", (tile.x0, tile.y0 + tile.tile), xytext=(2, 3),
                    textcoords="offset points", fontsize=8)
    ax.set(xlabel="x (m, local frame)", ylabel="y (m)")
    _title(ax, "Top view by class (highest point per pixel, gaps < 1 m filled)", pad=14)   # over the tile's label
    _class_legend(ax, classes_present, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    return fig


def write_tile_figure(path, tile) -> None:
    """Write :func:`tile_figure` to ``path``."""
    _save(tile_figure(tile), path)


def tile_figure(tile):
    """The tile seen from the south: by class, its woody parts only, and its trees by instance.

    :param tile: a :class:`~.quicklook.SideTile`; the z axis spans the ground to the highest point.
    """
    pts = tile.points()
    x_range, z_range = tile.x_range, tile_z_range(pts)
    cls = pts["classification"]
    present = _codes(np.bincount(cls, minlength=256))
    woody = _WOODY[cls]
    is_tree = _TREE[cls]
    palette = instance_palette(int(pts["instance"].max(initial=0)))
    # Only the points in front are coloured; the first and last panels show the same points.
    shape, pixels, front = front_points(pts, x_range, z_range)
    by_instance = np.where(is_tree[front, None], palette[pts["instance"][front]], np.uint8(NON_TREE_GREY))
    woody_shape, woody_pixels, woody_front = front_points(pts[woody], x_range, z_range)
    panels = [
        ("by class", paint(shape, pixels, CLASS_COLOURS[cls[front]]), present),
        ("woody parts only", paint(woody_shape, woody_pixels, CLASS_COLOURS[cls[woody][woody_front]]),
         [c for c in present if _WOODY[c]]),
        ("trees by instance", paint(shape, pixels, by_instance), None),
    ]
    panel_in = 3.6                                   # width of one panel's tile, inches
    height_in = min(panel_in * (z_range[1] - z_range[0]) / tile.tile, MAX_TILE_HEIGHT_IN)   # a narrow plot's tile is thin
    rows = max(len(present), 10) / 2          # legend rows (two columns; the instances' legend has up to 10)
    top, bottom = 0.25, 0.45 + LEGEND_DROP_IN + 0.25 * rows       # title; ticks, x label and legend
    fig = _figure(3 * (panel_in + 0.45) + 0.4, top + height_in + bottom, left=0.6, right=0.1, bottom=bottom, top=top,
                  between=0.45 / panel_in)
    axes = fig.subplots(1, 3, sharey=True)
    for ax, (title, image, codes) in zip(axes, panels):
        ax.imshow(image, extent=(*x_range, *z_range), interpolation="nearest")
        _title(ax, f"{tile.tile:g} m tile from the south: {title}", fontsize=9)
        ax.set(xlabel="x (m)", xticks=np.arange(np.ceil(x_range[0] / 5) * 5, x_range[1] - 1, 5))   # no label at the shared edges
        ax.set_anchor("N")      # spare height goes below, where the legend is
        if codes:
            _class_legend(ax, codes, ncol=2, **_below(ax))
        elif codes is None:
            _instance_legend(ax, pts["instance"][is_tree], _field(pts, "treeid", is_tree), palette)
    axes[0].set_ylabel("z (m)")
    return fig


def tile_z_range(points) -> tuple[float, float]:
    """From below the lowest point to above the highest: the whole height of the tile's trees."""
    if len(points) == 0:
        return 0.0, 1.0
    return float(points["z"].min()) - 0.5, float(points["z"].max()) + 1.0


def _field(points, name: str, rows):
    """``points[name][rows]``, or None when the points have no such field."""
    return points[name][rows] if name in points.dtype.names else None


def _codes(by_class) -> list[int]:
    """The class codes with a non-zero count in ``by_class`` (256,)."""
    return [int(c) for c in np.flatnonzero(by_class)]


def _instance_legend(ax, instance, treeid, palette, most: int = 8) -> None:
    """The legend of the trees-by-instance panel: the ``most`` instances with the most points, by name.

    :param instance: (n,) the instance ids of the tree points; ``treeid`` (n,) their treeids, or None.
    """
    from matplotlib.patches import Patch
    by_id = np.bincount(instance)
    ids = np.flatnonzero(by_id)
    counts = by_id[ids]
    names = {}
    if treeid is not None:    # each instance's treeid at its last point
        last = np.full(len(by_id), -1, np.int64)
        np.maximum.at(last, instance, np.arange(len(instance)))
        names = dict(zip(ids.tolist(), treeid[last[ids]].tolist()))
    shown = ids[np.argsort(-counts)][:most]
    handles = [Patch(color=palette[i] / 255, label=instance_label(int(i), names.get(int(i)))) for i in shown]
    if len(ids) > most:
        handles.append(Patch(color="white", label=f"... {len(ids) - most} more"))
    handles.append(Patch(color=np.full(3, NON_TREE_GREY / 255), label="not a tree"))
    ax.legend(handles=handles, fontsize=8, ncol=2, **_below(ax))


def instance_label(instance: int, treeid: int | None) -> str:
    """A legend's name for an instance of a tree class: ``tree 7 (tree03)``, its model as the plan, the
    volumes table and ``mitsuforest trees`` name it (an archetype or an imported tree alike); an instance
    of no tree model (treeid 0: a HELIOS++ part) is ``object 7``."""
    if treeid == 0:
        return f"object {instance}"
    return f"tree {instance}" + (f" (tree{treeid:02d})" if treeid is not None else "")


def write_profile_figure(path, counts) -> None:
    """Write :func:`profile_figure` to ``path``."""
    _save(profile_figure(counts), path)


def profile_figure(counts):
    """Returns by height above the ground and class (log scale: the ground outnumbers the canopy).

    :param counts: a :class:`~.profile.ReturnCounts`.
    """
    edges = counts.bin_edges
    rows = np.flatnonzero(counts.by_height.sum(1))
    fig = _figure(6.5, 5.5, left=0.75, right=0.2, bottom=0.6, top=0.4)
    ax = fig.add_subplot()
    if len(rows):
        lo, hi = rows[0], rows[-1] + 1
        for c in _codes(counts.by_height.sum(0)):
            n = counts.by_height[lo:hi, c]
            ax.stairs(n, edges[lo:hi + 1], orientation="horizontal", color=CLASS_COLOURS[c] / 255, lw=1.6,
                      label=f"{class_name(c)} ({n.sum():,})", baseline=None)
        ax.set_ylim(edges[lo], edges[hi])
    _log_scale(ax, "x")
    ax.set(xlabel=f"returns per {edges[1] - edges[0]:g} m of height (log)", ylabel="height above the ground (m)")
    _title(ax, "Vertical profile: returns by height and class")
    ax.grid(alpha=0.3)
    if len(rows):
        ax.legend(fontsize=8, loc="upper right")
    return fig


def write_returns_figure(path, pulses_by_returns: np.ndarray, counts) -> None:
    """Write :func:`returns_figure` to ``path``."""
    _save(returns_figure(pulses_by_returns, counts), path)


def returns_figure(pulses_by_returns: np.ndarray, counts):
    """Left: pulses by their number of returns; right: each return number's points split by class.

    :param pulses_by_returns: (k,) pulses with 0, 1, ... returns (entry 0 is not drawn).
    """
    fig = _figure(11, 4.8, left=0.8, right=1.55, bottom=0.6, top=0.4, between=0.2)
    left, right = fig.subplots(1, 2)
    n = np.flatnonzero(pulses_by_returns)
    n = n[n > 0]
    pulses = np.asarray(pulses_by_returns, float)[n]
    if len(n):
        bars = left.bar(n, pulses, color="#4a7bb7")
        total = pulses.sum()
        left.bar_label(bars, [f"{p / total:.1%}" if p / total >= 0.0005 else "" for p in pulses], fontsize=7)
        _log_scale(left, "y")
        left.set_xticks(n)
    left.set(xlabel="returns per pulse", ylabel="pulses (log)")
    _title(left, "Returns histogram")
    by_return = counts.by_return[1:]
    numbers = np.flatnonzero(by_return.sum(1)) + 1
    bottom = np.zeros(len(numbers))
    for c in _codes(by_return.sum(0)):
        share = by_return[numbers - 1, c] / np.maximum(by_return[numbers - 1].sum(1), 1)
        right.bar(numbers, share * 100, bottom=bottom, color=CLASS_COLOURS[c] / 255, label=class_name(c))
        bottom += share * 100
    right.set_xticks(numbers)
    right.set(xlabel="return number", ylabel="share of the points (%)", ylim=(0, 100))
    _title(right, "Classes by return number")
    if len(numbers):
        right.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    return fig
