"""Pictures that explain themselves (scenelabel.viz.pictures): captioned render panels with a class
legend and the view's metrics, the build's renders/<view>.png, the floor plan with a legend."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from scenelabel import FREE, UNKNOWN, OccupancyMap, build, preset, write_toy_scene
from scenelabel.errors import InputError
from scenelabel.maps.exports import class_palette
from scenelabel.query.answers import RenderResult
from scenelabel.viz.pictures import (
    CAPTION_HEIGHT,
    COLORBAR_HEIGHT,
    GAP,
    LEGEND_ENTRY_WIDTH,
    LEGEND_ROW_HEIGHT,
    MAX_PANEL_WIDTH,
    MIN_PANEL_WIDTH,
    TITLE_HEIGHT,
    Panel,
    evaluation_panels,
    legend_entries,
    nice_length,
    panel_figure,
    panel_layout,
    view_title,
    write_floor_plan_picture,
    write_panels,
)

CLASSES = {1: "floor", 3: "box", 5: "chair"}  # chair: in the vocabulary, in no image
COLORS = {1: (200, 100, 50)}
IGNORE = 255
H, W = 30, 40


def _view():
    """A render and its truth: floor and box rendered, the truth's box a little higher, a row ignored."""
    rng = np.random.default_rng(0)
    label = np.full((H, W), FREE)
    label[10:25, 4:18] = 1
    label[5:20, 22:36] = 3
    true = label.copy()
    true[10:12, 4:18] = 3
    true[0:2] = IGNORE
    depth = np.where(label >= 0, 2.0 + rng.random((H, W)), 7.0)
    render = RenderResult(rng.random((H, W, 3), dtype=np.float32), depth, np.ones((H, W)), np.zeros((H, W, 2)), label)
    return rng.random((H, W, 3)), render, true, np.where(true >= 0, 2.5, 0.0)


def _expected_size(n_panels, image_width, image_height, n_legend, depth_panels=True):
    scale = math.ceil(MIN_PANEL_WIDTH / image_width) if image_width < MIN_PANEL_WIDTH else 1
    width = n_panels * image_width * scale + (n_panels + 1) * GAP
    rows = math.ceil(n_legend / max(1, (width - 2 * GAP) // LEGEND_ENTRY_WIDTH)) if n_legend else 0
    bar = COLORBAR_HEIGHT if depth_panels else 0
    return width, TITLE_HEIGHT + CAPTION_HEIGHT + image_height * scale + GAP + bar + rows * LEGEND_ROW_HEIGHT + GAP


def test_panels_picture_has_its_size_captions_title_and_legend(tmp_path):
    photo, render, true, true_depth = _view()
    panels = evaluation_panels(photo, render, render.label, true, true_depth, IGNORE)
    captions = [p.caption for p in panels]
    assert captions[:5] == ["ground truth", "rgb", "labels", "smoothed labels", "true labels"]
    assert captions[5].startswith("depth ") and captions[6] == "true depth" and captions[7].startswith("label errors ")
    title = view_title("000", {"psnr": 25.1234, "ssim": 0.8, "miou": 0.7, "depth_error": {"abs_rel": 0.03}})
    assert "PSNR 25.12 dB" in title and "mIoU 0.700" in title and title.startswith("view 000")

    pic = write_panels(tmp_path / "000.png", panels, CLASSES, COLORS, title, IGNORE)
    assert pic.captions == captions and pic.title == title
    # the legend: exactly the classes in the label panels (not chair), then the codes without a class
    assert [c for c, _ in pic.legend if c >= 0 and c != IGNORE] == [1, 3]
    assert dict(pic.legend) == {1: "floor", 3: "box", FREE: "nothing hit / free", IGNORE: "unlabelled (ignored)"}

    image = np.asarray(Image.open(pic.path).convert("RGB"))
    assert (image.shape[1], image.shape[0]) == pic.size == _expected_size(len(panels), W, H, len(pic.legend))
    assert image.std() > 20  # not blank
    colours = {tuple(c) for c in image.reshape(-1, 3)}
    palette = class_palette(CLASSES, COLORS)
    assert palette[1] in colours and palette[3] in colours  # the label panels draw the class colours
    assert palette[5] not in colours

    fig, layout, legend = panel_figure(panels, CLASSES, COLORS, title, IGNORE)
    texts = [t.get_text() for t in fig.texts]
    assert texts == [title, *captions, *[name for _, name in legend]]
    assert (layout.width, layout.height) == pic.size
    # one colour bar per depth panel, its ticks inside the depth range of the caption
    vmin, vmax = panels[5].vmin, panels[5].vmax
    bars = [ax for ax in fig.axes if ax.get_label().startswith("colour bar: ")]
    assert len(bars) == 2
    np.testing.assert_allclose(bars[0].get_xlim(), (vmin, vmax))
    assert sum(vmin <= t <= vmax for t in bars[0].get_xticks()) >= 2
    bar_rows = image[TITLE_HEIGHT + CAPTION_HEIGHT + layout.panel_height:][:COLORBAR_HEIGHT].astype(int)
    r, g, b = bar_rows[..., 0], bar_rows[..., 1], bar_rows[..., 2]
    assert ((r > 200) & (g > 200) & (b < 100)).any() and ((r < 90) & (g < 30) & (b > 60)).any()  # viridis' two ends


def test_pictures_without_depth_have_no_colour_bar():
    layout = panel_layout([Panel("a", np.zeros((30, 40, 3)))], 0)
    assert layout.colorbar_height == 0
    assert panel_layout([Panel("d", np.ones((30, 40)), "depth")], 0).colorbar_height == COLORBAR_HEIGHT


def test_label_errors_panel_marks_wrong_pixels_only():
    photo, render, true, _ = _view()
    errors = evaluation_panels(photo, render, None, true, None, IGNORE)[-1]
    wrong = (render.label != true) & (true != IGNORE)
    assert errors.caption == f"label errors {100 * wrong.sum() / (true != IGNORE).sum():.1f}%"
    assert (errors.image[wrong] == (220, 30, 30)).all() and not (errors.image[~wrong] == (220, 30, 30)).all(-1).any()


def test_a_free_pixel_is_right_where_the_render_hit_nothing():
    """A true FREE pixel (an object capture's background) is right where the render says FREE or
    UNKNOWN (a ray outside the modelled bounds), wrong where it hit a class; as the scores count it."""
    photo, render, _, _ = _view()
    true = np.full(render.label.shape, FREE)
    label = render.label.copy()
    label[0, :3] = [FREE, UNKNOWN, 0]
    errors = evaluation_panels(photo, dataclasses.replace(render, label=label), None, true, None, IGNORE)[-1]
    wrong = label >= 0
    assert (errors.image[wrong] == (220, 30, 30)).all() and not (errors.image[~wrong] == (220, 30, 30)).all(-1).any()
    assert errors.caption == f"label errors {100 * wrong.mean():.1f}%"


def test_legend_lists_the_classes_present_in_any_label_panel():
    label = np.zeros((4, 5), np.int64)
    label[0, 0] = UNKNOWN
    panels = [Panel("labels", label, "labels"), Panel("true labels", np.full((4, 5), 5), "labels"),
              Panel("rgb", np.full((4, 5, 3), 9, np.uint8))]
    classes = {0: "wall", 5: "chair", 9: "lamp"}
    assert legend_entries(panels, classes) == [(0, "wall"), (5, "chair"), (UNKNOWN, "unknown")]
    assert legend_entries([panels[2]], {0: "wall"}) == []


def test_unlabelled_builds_draw_colour_and_depth_without_a_legend(tmp_path):
    photo, render, _, _ = _view()
    panels = evaluation_panels(photo, render, labels=False)
    assert [p.caption for p in panels][:2] == ["ground truth", "rgb"] and len(panels) == 3
    pic = write_panels(tmp_path / "v.png", panels, {0: "unlabelled"}, title=view_title("v", {"psnr": 20.0}))
    assert pic.legend == [] and pic.size == _expected_size(3, W, H, 0)


def test_panel_scale_keeps_pixels_square_and_bounds_the_width():
    small = panel_layout([Panel("a", np.zeros((30, 40, 3)))], 0)
    assert small.scale == 4 and (small.panel_width, small.panel_height) == (160, 120)
    large = panel_layout([Panel("a", np.zeros((600, 800, 3)))], 0)
    assert large.panel_width == MAX_PANEL_WIDTH and large.panel_height == 300
    with pytest.raises(InputError, match="kind"):
        panel_layout([Panel("a", np.zeros((3, 4)), "mask")], 0)
    with pytest.raises(InputError, match="at least one panel"):
        panel_layout([], 0)


def test_nice_length():
    assert nice_length(1.0) == 0.2 and nice_length(8.0) == 1.0 and nice_length(0.8) == 0.1 and nice_length(30) == 5


def _box_map():
    label = np.full((8, 6, 5), FREE, np.int16)
    label[:, :, 0] = 1
    label[2:4, 2:4, 1:4] = 3
    label[6:, :, 1:] = UNKNOWN
    occupancy = np.where(label >= 0, 1.0, 0.0).astype(np.float32)
    return OccupancyMap(label, occupancy, 0.1, [0.0, 0.0, 0.0], dict(CLASSES), 0.1, units="metre")


def test_floor_plan_picture_has_a_legend_and_a_scale_bar(tmp_path):
    pic = write_floor_plan_picture(_box_map(), tmp_path / "plan_legend.png", robot_height=0.3)
    # the band is above the floor: the box, free and unknown cells; no floor, no chair
    assert pic.legend == [(3, "box"), (FREE, "free"), (UNKNOWN, "unknown")]
    assert pic.captions == ["x (m)", "y (m)", "0.1 m"] and "floor plan" in pic.title
    image = np.asarray(Image.open(pic.path).convert("RGB"))
    assert (image.shape[1], image.shape[0]) == pic.size and image.std() > 20
    assert class_palette(CLASSES)[3] in {tuple(c) for c in image.reshape(-1, 3)}


def test_nav2_export_writes_the_legend_picture_beside_the_map(tmp_path):
    store = _box_map().to_zarr(tmp_path / "box.zarr")
    run = [sys.executable, "-m", "scenelabel", "export", str(store), str(tmp_path / "plan"), "--format", "nav2"]
    proc = subprocess.run([*run, "--robot-height", "0.3", "--legend"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "plan_legend.png" in proc.stdout and (tmp_path / "plan_legend.png").is_file()
    assert Image.open(tmp_path / "plan_labels.png").size == (8, 6)  # the Nav2 label image stays one pixel per cell


@pytest.mark.slow
def test_build_writes_captioned_renders(tmp_path):
    scene = write_toy_scene(tmp_path / "scene", n_train=7, n_test=1, width=32, height=24)
    config = preset("quick", {"sampling": {"n_steps": 48, "grid_resolution": 16}})
    config.train.steps, config.train.batch_rays, config.output.write_map = 10, 128, False
    result = build(scene, tmp_path / "out", config, progress=False)
    picture = Image.open(tmp_path / "out" / "renders" / "000.png")
    # ground truth, rgb, labels, smoothed labels, true labels, depth, true depth, label errors; legend rows
    width, height = _expected_size(8, 32, 24, 0)
    assert picture.size[0] == width and picture.size[1] >= height + LEGEND_ROW_HEIGHT
    assert result.metrics["per_view"][0]["view"] == "000"
