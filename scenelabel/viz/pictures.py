"""Pictures that explain themselves: captioned render panels and a floor plan with a legend.

- :func:`evaluation_panels` -> :func:`write_panels`: a held-out view as a row of captioned panels
  (ground truth, rgb, labels, smoothed labels, true labels, depth, true depth, label errors), a
  legend of the classes that appear in the label panels, and the view's metrics in the title.
  ``build`` writes one per held-out view, for up to 8 of them, to ``renders/<view>.png``.
- :func:`write_floor_plan_picture`: a map's floor plan (:func:`scenelabel.maps.exports.floor_plan`)
  in world coordinates with a legend of the classes present, free and unknown, and a scale bar
  (``scenelabel export MAP OUT --format nav2 --legend`` writes ``OUT_legend.png``). The Nav2
  ``OUT_labels.png`` stays one pixel per cell, aligned with the PGM.

Drawn with matplotlib's Agg canvas (``matplotlib.figure.Figure``, no pyplot state), imported
inside the functions: importing this module loads no matplotlib.

Panel layout (:func:`panel_layout`, pixels): every panel is shown at the same size, its image
scaled by ``scale`` (an integer > 1 for images narrower than :data:`MIN_PANEL_WIDTH`, pixels kept
square and sharp; ``MAX_PANEL_WIDTH / width`` for wider ones; else 1). The picture is
``n * panel_width + (n + 1) * GAP`` wide and ``TITLE_HEIGHT + CAPTION_HEIGHT + panel_height +
GAP + COLORBAR_HEIGHT + legend rows * LEGEND_ROW_HEIGHT + GAP`` high (no colour bar without depth
panels, no legend rows without label panels). Each depth panel has its colour bar below it, in
world units.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from scenelabel._files import atomic_write_bytes
from scenelabel.errors import InputError
from scenelabel.maps.codes import FREE, UNKNOWN
from scenelabel.maps.exports.floorplan import FREE_RGB, UNKNOWN_RGB, colors_from_plan, floor_plan
from scenelabel.maps.exports.palette import class_palette, default_color
from scenelabel.maps.occupancy_map import OccupancyMap
from scenelabel.metrics import no_hit_as_free
from scenelabel.query.answers import RenderResult
from scenelabel.query.postprocess import IGNORE_COLOR, NO_CLASS_COLOR

__all__ = [
    "MIN_PANEL_WIDTH",
    "MAX_PANEL_WIDTH",
    "GAP",
    "TITLE_HEIGHT",
    "CAPTION_HEIGHT",
    "LEGEND_ROW_HEIGHT",
    "COLORBAR_HEIGHT",
    "LEGEND_ENTRY_WIDTH",
    "ERROR_RGB",
    "UNKNOWN_COLOR",
    "CORRECT_RGB",
    "Panel",
    "PanelLayout",
    "Picture",
    "evaluation_panels",
    "view_title",
    "panel_layout",
    "legend_entries",
    "panel_figure",
    "write_panels",
    "nice_length",
    "floor_plan_figure",
    "write_floor_plan_picture",
]

MIN_PANEL_WIDTH = 160
"""Pixels: narrower images are enlarged by an integer factor to at least this width."""
MAX_PANEL_WIDTH = 400
"""Pixels: wider images are shrunk to this width."""
GAP = 8
"""Pixels between panels and around the picture."""
TITLE_HEIGHT = 34
CAPTION_HEIGHT = 22
LEGEND_ROW_HEIGHT = 22
COLORBAR_HEIGHT = 30
"""Pixels below the panels for the depth panels' colour bars (a bar and its tick labels)."""
LEGEND_ENTRY_WIDTH = 150
"""Pixels per legend entry (a swatch and a name): the legend wraps into rows of this many per width."""
DPI = 100
DEPTH_COLORMAP = "viridis"
NO_DEPTH_RGB = (128, 128, 128)
"""Depth panels: pixels without a depth (nothing hit, no true depth)."""
ERROR_RGB = (220, 30, 30)
"""Label-error panel: a pixel whose label differs from the true one."""
CORRECT_RGB = (225, 225, 225)
"""Label-error panel: a pixel labelled as the truth (ignored pixels are IGNORE_COLOR)."""
UNKNOWN_COLOR = (100, 100, 100)
"""Label panels: UNKNOWN pixels (rays that never enter the bounds); FREE ones are NO_CLASS_COLOR."""
NO_HIT_NAME = "nothing hit / free"
UNKNOWN_NAME = "unknown"
IGNORED_NAME = "unlabelled (ignored)"


class Panel(NamedTuple):
    """One captioned image of a picture.

    caption: the text above it.
    image: ``kind`` "rgb": [H, W, 3] float in [0, 1] or uint8; "labels": [H, W] int class ids
        (FREE, UNKNOWN and ``ignore_index`` allowed); "depth": [H, W] float, NaN where there is none.
    kind: "rgb", "labels" or "depth".
    vmin, vmax: the colour range of a depth panel (None: the panel's own finite range).
    """

    caption: str
    image: np.ndarray
    kind: str = "rgb"
    vmin: float | None = None
    vmax: float | None = None


class PanelLayout(NamedTuple):
    """Pixel sizes of a panel picture (see the module docstring)."""

    width: int
    height: int
    panel_width: int
    panel_height: int
    scale: float
    legend_columns: int
    legend_rows: int
    colorbar_height: int


class Picture(NamedTuple):
    """What a written picture holds.

    path: the PNG.
    size: (width, height) pixels.
    title: the title line.
    captions: the panels' captions, left to right (for a floor plan: the axis labels and the scale bar).
    legend: (code, name) of each legend entry, in order: class ids ascending, then the codes
        without a class present (FREE, UNKNOWN, the ignore index) with their descriptions.
    """

    path: Path
    size: tuple[int, int]
    title: str
    captions: list[str]
    legend: list[tuple[int, str]]


# --------------------------------------------------------------------------------------------
# Panels of a held-out view
# --------------------------------------------------------------------------------------------


def _finite_range(*images: np.ndarray | None) -> tuple[float, float] | None:
    values = [im[np.isfinite(im)] for im in images if im is not None]
    values = [v for v in values if v.size]
    if not values:
        return None
    lo, hi = min(float(v.min()) for v in values), max(float(v.max()) for v in values)
    return (lo, hi) if hi > lo else (lo, lo + 1e-6)


def evaluation_panels(
    photo: np.ndarray,
    render: RenderResult,
    smoothed_label: np.ndarray | None = None,
    true_label: np.ndarray | None = None,
    true_depth: np.ndarray | None = None,
    ignore_index: int | None = None,
    labels: bool = True,
) -> list[Panel]:
    """The panels of a held-out view: ground truth | rgb | labels | smoothed labels | true labels |
    depth | true depth | label errors (those whose inputs are given).

    Args:
        photo: [H, W, 3] the view's photo (float in [0, 1] or uint8).
        render: the field's render of the view (:meth:`SemanticField.render_camera`).
        smoothed_label: [H, W] the render's labels after smoothing, or None.
        true_label: [H, W] the view's mask (external ids, ``ignore_index``), or None.
        true_depth: [H, W] the view's true depth (along the ray, 0 where none), or None.
        ignore_index: the mask's value of unlabelled pixels.
        labels: draw the label panels (False for a build without labels: colour and depth only).
    Returns:
        list of :class:`Panel`. Rendered depth is NaN where nothing was hit (label < 0); both
        depth panels share one colour range, given in the depth caption. A true FREE pixel (its ray
        meets nothing) is right where the render hit nothing (FREE or UNKNOWN), as the scores count it.
    """
    panels = [Panel("ground truth", np.asarray(photo)), Panel("rgb", np.asarray(render.rgb))]
    label = np.asarray(render.label)
    if labels:
        panels.append(Panel("labels", label, "labels"))
        if smoothed_label is not None:
            panels.append(Panel("smoothed labels", np.asarray(smoothed_label), "labels"))
        if true_label is not None:
            panels.append(Panel("true labels", np.asarray(true_label), "labels"))
    depth = np.where(label >= 0, np.asarray(render.depth, np.float64), np.nan)
    truth = None
    if true_depth is not None:
        truth = np.asarray(true_depth, np.float64)
        truth = np.where(truth > 0, truth, np.nan)
    span = _finite_range(depth, truth)
    vmin, vmax = (None, None) if span is None else span
    caption = "depth" if span is None else f"depth {vmin:.3g} to {vmax:.3g}"
    panels.append(Panel(caption, depth, "depth", vmin, vmax))
    if truth is not None:
        panels.append(Panel("true depth", truth, "depth", vmin, vmax))
    if labels and true_label is not None:
        true_label = np.asarray(true_label)
        counted = np.ones(true_label.shape, bool) if ignore_index is None else true_label != ignore_index
        wrong = counted & (no_hit_as_free(label) != true_label)  # as the held-out scores count it
        errors = np.empty(true_label.shape + (3,), np.uint8)
        errors[...] = CORRECT_RGB
        errors[wrong] = ERROR_RGB
        errors[~counted] = IGNORE_COLOR
        share = 100.0 * wrong.sum() / max(int(counted.sum()), 1)
        panels.append(Panel(f"label errors {share:.1f}%", errors))
    return panels


def view_title(name: str, metrics: Mapping[str, Any] | None = None) -> str:
    """``view NAME: PSNR 27.31 dB, SSIM 0.912, mIoU 0.874, depth error 0.031`` from a view's
    metrics (``metrics.json``'s ``per_view`` entries); the figures it lacks are left out."""
    metrics = metrics or {}
    parts = []
    if metrics.get("psnr") is not None:
        parts.append(f"PSNR {metrics['psnr']:.2f} dB")
    if metrics.get("ssim") is not None:
        parts.append(f"SSIM {metrics['ssim']:.3f}")
    if metrics.get("miou") is not None and np.isfinite(metrics["miou"]):
        parts.append(f"mIoU {metrics['miou']:.3f}")
    depth = metrics.get("depth_error")
    if isinstance(depth, Mapping) and depth.get("abs_rel") is not None:
        parts.append(f"depth error {depth['abs_rel']:.3f} (abs. rel.)")
    return f"view {name}" + (": " + ", ".join(parts) if parts else "")


def _check_panels(panels: Sequence[Panel]) -> None:
    if not panels:
        raise InputError("a picture needs at least one panel", field="panels")
    for p in panels:
        if p.kind not in ("rgb", "labels", "depth"):
            raise InputError(f"panel kind must be 'rgb', 'labels' or 'depth', got {p.kind!r}", field="panels")
        want = 3 if p.kind == "rgb" else 2
        if np.ndim(p.image) != want or (want == 3 and np.shape(p.image)[2] != 3):
            raise InputError(f"panel {p.caption!r}: a {p.kind} image must be {'[H, W, 3]' if want == 3 else '[H, W]'}, "
                             f"got shape {np.shape(p.image)}", field="panels")


def legend_entries(
    panels: Sequence[Panel], classes: Mapping[int, str], ignore_index: int | None = None
) -> list[tuple[int, str]]:
    """(code, name) of every label code in the label panels: the class ids present, ascending,
    then FREE, UNKNOWN and ``ignore_index`` when present (with what they mean). Ids missing from
    ``classes`` are named ``class ID``."""
    codes: set[int] = set()
    for p in panels:
        if p.kind == "labels":
            codes.update(np.unique(np.asarray(p.image)).tolist())
    special = {FREE: NO_HIT_NAME, UNKNOWN: UNKNOWN_NAME}
    if ignore_index is not None:
        special[int(ignore_index)] = IGNORED_NAME
    named = [(c, classes.get(c, f"class {c}")) for c in sorted(codes) if c >= 0 and c not in special]
    named += [(c, special[c]) for c in special if c in codes]
    named += [(c, f"code {c}") for c in sorted(codes) if c < 0 and c not in special]
    return named


def _code_colors(
    codes: Sequence[int], classes: Mapping[int, str], class_colors: Mapping[int, Any] | None, ignore_index: int | None
) -> dict[int, tuple[int, int, int]]:
    palette = class_palette({c: classes.get(c, "") for c in codes if c >= 0}, class_colors)
    colors = {}
    for c in codes:
        if ignore_index is not None and c == ignore_index:
            colors[c] = tuple(IGNORE_COLOR)
        elif c >= 0:
            colors[c] = palette.get(c, default_color(c))
        elif c == UNKNOWN:
            colors[c] = UNKNOWN_COLOR
        else:
            colors[c] = tuple(NO_CLASS_COLOR)
    return colors


def _label_rgb(label: np.ndarray, colors: Mapping[int, tuple[int, int, int]]) -> np.ndarray:
    label = np.asarray(label, np.int64)
    out = np.zeros(label.shape + (3,), np.uint8)
    for code in np.unique(label).tolist():
        out[label == code] = colors[code]
    return out


def panel_layout(panels: Sequence[Panel], n_legend_entries: int) -> PanelLayout:
    """Pixel sizes of :func:`panel_figure`'s picture (rules in the module docstring); panels are
    shown at the size of the largest one's image."""
    _check_panels(panels)
    h = max(int(np.shape(p.image)[0]) for p in panels)
    w = max(int(np.shape(p.image)[1]) for p in panels)
    if w < MIN_PANEL_WIDTH:
        scale = float(math.ceil(MIN_PANEL_WIDTH / w))
    elif w > MAX_PANEL_WIDTH:
        scale = MAX_PANEL_WIDTH / w
    else:
        scale = 1.0
    pw, ph = int(round(w * scale)), int(round(h * scale))
    n = len(panels)
    width = n * pw + (n + 1) * GAP
    columns = max(1, (width - 2 * GAP) // LEGEND_ENTRY_WIDTH)
    rows = math.ceil(n_legend_entries / columns) if n_legend_entries else 0
    bar = COLORBAR_HEIGHT if any(p.kind == "depth" for p in panels) else 0
    height = TITLE_HEIGHT + CAPTION_HEIGHT + ph + GAP + bar + rows * LEGEND_ROW_HEIGHT + GAP
    return PanelLayout(width, height, pw, ph, scale, columns, rows, bar)


def _depth_colors(panel: Panel):
    """(cmap, norm) of a depth panel: viridis over [vmin, vmax] (None: the panel's own finite range),
    NO_DEPTH_RGB where there is no depth."""
    import matplotlib
    from matplotlib.colors import Normalize

    cmap = matplotlib.colormaps[DEPTH_COLORMAP].with_extremes(bad=np.asarray(NO_DEPTH_RGB) / 255.0)
    span = _finite_range(np.asarray(panel.image, np.float64)) or (0.0, 1.0)
    vmin = span[0] if panel.vmin is None else panel.vmin
    vmax = span[1] if panel.vmax is None else panel.vmax
    return cmap, Normalize(vmin, vmax)


def _display(panel: Panel, colors: Mapping[int, tuple[int, int, int]], size: tuple[int, int], depth_colors=None) -> np.ndarray:
    """[h, w, 3] uint8: the pixels ``panel`` shows at ``size`` (w, h): class colours, the depth
    colour map (``depth_colors``: :func:`_depth_colors` of the panel), or the photo; enlarged by
    repeating pixels, shrunk by averaging (PIL's box filter)."""
    from PIL import Image

    image = np.asarray(panel.image)
    if panel.kind == "labels":
        rgb = _label_rgb(image, colors)
    elif panel.kind == "depth":
        cmap, norm = depth_colors
        rgb = cmap(norm(np.ma.masked_invalid(image.astype(np.float64))), bytes=True)[..., :3]
    elif image.dtype != np.uint8:
        rgb = np.round(np.clip(image.astype(np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)
    else:
        rgb = image
    h, w = rgb.shape[:2]
    if (w, h) == size:
        return rgb
    if size[0] % w == 0 and size[1] % h == 0 and size[0] // w == size[1] // h:
        return np.repeat(np.repeat(rgb, size[1] // h, axis=0), size[0] // w, axis=1)
    smaller = size[0] < w
    return np.asarray(Image.fromarray(rgb).resize(size, Image.Resampling.BOX if smaller else Image.Resampling.NEAREST))


def panel_figure(
    panels: Sequence[Panel],
    classes: Mapping[int, str],
    class_colors: Mapping[int, Any] | None = None,
    title: str = "",
    ignore_index: int | None = None,
):
    """The picture of ``panels`` as a matplotlib Figure (Agg): the title, each panel with its
    caption above it, and a legend of the label codes present (:func:`legend_entries`) below.

    Args:
        panels: the panels, left to right.
        classes: class id -> name (names of the legend).
        class_colors: class id -> (r, g, b) 0-255 (others: :func:`default_color`).
        title: the line above the panels (:func:`view_title`).
        ignore_index: the masks' value of unlabelled pixels (drawn black).
    Returns:
        (figure, layout, legend): a ``matplotlib.figure.Figure`` of ``layout.width x layout.height``
        pixels at its dpi, the :class:`PanelLayout`, and the legend's (code, name) entries.
        Its ``texts`` are the title, the captions (left to right), then the legend's names.
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    legend = legend_entries(panels, classes, ignore_index)
    layout = panel_layout(panels, len(legend))
    colors = _code_colors([c for c, _ in legend], classes, class_colors, ignore_index)
    W, H = layout.width, layout.height
    fig = Figure(figsize=(W / DPI, H / DPI), dpi=DPI, facecolor="white")

    def box(x: float, y_top: float, w: float, h: float) -> list[float]:  # pixels from the top-left -> figure fraction
        return [x / W, 1.0 - (y_top + h) / H, w / W, h / H]

    fig.text(0.5, 1.0 - (TITLE_HEIGHT / 2) / H, title, ha="center", va="center", fontsize=11, weight="bold")
    top = TITLE_HEIGHT + CAPTION_HEIGHT
    # the panels' pixels, drawn as one image at the figure's own pixels (no axes: an axes per panel
    # took most of the drawing time)
    strip = np.full((layout.panel_height, W, 3), 255, np.uint8)
    for n, panel in enumerate(panels):
        x = GAP + n * (layout.panel_width + GAP)
        fig.text((x + layout.panel_width / 2) / W, 1.0 - (TITLE_HEIGHT + CAPTION_HEIGHT / 2) / H, panel.caption,
                 ha="center", va="center", fontsize=9)
        depth_colors = _depth_colors(panel) if panel.kind == "depth" else None
        strip[:, x:x + layout.panel_width] = _display(panel, colors, (layout.panel_width, layout.panel_height), depth_colors)
        if depth_colors is not None:  # its colour bar, below it
            bar = fig.add_axes(box(x + 0.1 * layout.panel_width, top + layout.panel_height + GAP / 2,
                                   0.8 * layout.panel_width, 8), label=f"colour bar: {panel.caption}")
            fig.colorbar(ScalarMappable(depth_colors[1], depth_colors[0]), cax=bar, orientation="horizontal")
            bar.tick_params(labelsize=7, length=2, pad=1)
    fig.figimage(strip, xo=0, yo=H - top - layout.panel_height, origin="upper")
    legend_top = top + layout.panel_height + GAP + layout.colorbar_height
    for n, (code, name) in enumerate(legend):
        row, col = divmod(n, layout.legend_columns)
        x, y = GAP + col * LEGEND_ENTRY_WIDTH, legend_top + row * LEGEND_ROW_HEIGHT
        swatch = box(x, y + 4, 14, 14)
        fig.add_artist(Rectangle((swatch[0], swatch[1]), swatch[2], swatch[3], transform=fig.transFigure,
                                     facecolor=np.asarray(colors[code]) / 255.0, edgecolor="black", linewidth=0.5))
        label = name if len(name) <= 22 else name[:21] + "…"
        fig.text((x + 20) / W, 1.0 - (y + 11) / H, label, ha="left", va="center", fontsize=8)
    return fig, layout, legend


def _save(fig, path: Path, tight: bool = False) -> tuple[int, int]:
    """Write ``fig`` as PNG atomically; its (width, height) in pixels."""
    from PIL import Image

    buf = io.BytesIO()
    crop = {"bbox_inches": "tight", "pad_inches": 0.1} if tight else {}
    fig.savefig(buf, format="png", dpi=DPI, facecolor="white", **crop)
    data = buf.getvalue()
    atomic_write_bytes(path, data)
    with Image.open(io.BytesIO(data)) as im:
        return im.size


def write_panels(
    path: str | Path,
    panels: Sequence[Panel],
    classes: Mapping[int, str],
    class_colors: Mapping[int, Any] | None = None,
    title: str = "",
    ignore_index: int | None = None,
) -> Picture:
    """Draw :func:`panel_figure` and write it as a PNG (atomically).

    Args:
        path: the PNG to write.
        panels, classes, class_colors, title, ignore_index: see :func:`panel_figure`.
    Returns:
        :class:`Picture`: the path, its pixel size (``panel_layout``'s), the title, the captions
        and the legend.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError("the parent folder does not exist", path=path.parent)
    fig, _, legend = panel_figure(panels, classes, class_colors, title, ignore_index)
    size = _save(fig, path)
    return Picture(path, size, title, [p.caption for p in panels], legend)


# --------------------------------------------------------------------------------------------
# Floor plan
# --------------------------------------------------------------------------------------------


def nice_length(span: float, fraction: float = 0.2) -> float:
    """A scale bar's length: 1, 2 or 5 times a power of ten, the largest not above ``fraction * span``
    (at least the smallest such number below ``span``)."""
    if not (np.isfinite(span) and span > 0):
        raise InputError(f"span must be a positive number, got {span}", field="span")
    target = span * fraction
    power = 10.0 ** math.floor(math.log10(target))
    return max(m * power for m in (1.0, 2.0, 5.0) if m * power <= target * (1 + 1e-9))


def _length_label(length: float, units: str) -> str:
    unit = "m" if units == "metre" else "input units"
    return f"{length:g} {unit}"


def floor_plan_figure(
    occ_map: OccupancyMap, z_min: float | None = None, z_max: float | None = None, robot_height: float | None = None
):
    """The floor plan of ``occ_map`` (:func:`scenelabel.maps.exports.floor_plan`, the same band and
    colours as Nav2's ``_labels.png``) drawn in world x, y with a legend and a scale bar.

    Args:
        occ_map: the map.
        z_min, z_max, robot_height: the height band, see :func:`scenelabel.maps.exports.height_band`.
    Returns:
        (figure, title, captions, legend): the matplotlib Figure; its title; the axis labels and
        the scale bar's label; the legend's (code, name) entries: the classes present in the plan
        (ascending id), then FREE and UNKNOWN when present.
    """
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    plan = floor_plan(occ_map, z_min, z_max, robot_height)
    rgb = colors_from_plan(plan)  # [ny, nx, 3], row 0 = max y
    nx, ny = plan.label.shape
    x0, y0 = plan.origin_corner.tolist()
    x1, y1 = x0 + nx * plan.voxel_size, y0 + ny * plan.voxel_size
    cell_px = float(np.clip(600.0 / max(nx, ny), 2.0, 40.0))
    fig = Figure(figsize=(max(nx * cell_px, 200) / DPI + 2.4, max(ny * cell_px, 150) / DPI + 1.0), dpi=DPI)
    ax = fig.add_axes([0.1, 0.1, 0.6, 0.8])
    ax.imshow(rgb, extent=(x0, x1, y0, y1), origin="upper", interpolation="nearest")
    unit = "m" if plan.units == "metre" else "input units"
    captions = [f"x ({unit})", f"y ({unit})"]
    ax.set_xlabel(captions[0])
    ax.set_ylabel(captions[1])
    title = f"floor plan of z {plan.z_min:.3g} to {plan.z_max:.3g} ({plan.frame_id})"
    ax.set_title(title, fontsize=10)
    length = nice_length(x1 - x0)
    bar_label = _length_label(length, plan.units)
    ax.add_artist(AnchoredSizeBar(ax.transData, length, bar_label, loc="lower left", pad=0.4, borderpad=0.6,
                                  sep=3, frameon=True, color="black", size_vertical=(y1 - y0) / 150))
    captions.append(bar_label)
    palette = class_palette(plan.classes, plan.class_colors)
    present = sorted(np.unique(plan.label[plan.label >= 0]).tolist())
    legend = [(c, plan.classes.get(c, f"class {c}")) for c in present]
    handles = [Patch(facecolor=np.asarray(palette.get(c, default_color(c))) / 255, edgecolor="black", label=n)
               for c, n in legend]
    for code, name, color in ((FREE, "free", FREE_RGB), (UNKNOWN, "unknown", UNKNOWN_RGB)):
        if (plan.label == code).any():
            legend.append((code, name))
            handles.append(Patch(facecolor=np.asarray(color) / 255, edgecolor="black", label=name))
    if handles:
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.03, 1.0), fontsize=8, frameon=False)
    return fig, title, captions, legend


def write_floor_plan_picture(
    occ_map: OccupancyMap,
    path: str | Path,
    z_min: float | None = None,
    z_max: float | None = None,
    robot_height: float | None = None,
) -> Picture:
    """Write :func:`floor_plan_figure` as a PNG (atomically, cropped to its content).

    Args:
        occ_map: the map.
        path: the PNG to write.
        z_min, z_max, robot_height: the height band, see :func:`scenelabel.maps.exports.height_band`.
    Returns:
        :class:`Picture` (captions: the axis labels and the scale bar's label).
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError("the parent folder does not exist", path=path.parent)
    fig, title, captions, legend = floor_plan_figure(occ_map, z_min, z_max, robot_height)
    size = _save(fig, path, tight=True)
    return Picture(path, size, title, captions, legend)
