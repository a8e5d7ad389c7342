"""The web viewer (scenelabel.viz.viewer, ``scenelabel view``): the scene it serves, its point
queries and renders, its panels, the command; and what a real (headless) browser shows."""

import socket
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest

from scenelabel import FREE, UNKNOWN, OccupancyMap
from scenelabel.errors import InputError
from scenelabel.viz.browser import HeadlessBrowser, colour_fraction, find_chromium
from scenelabel.viz.viewer import ViewerApp, frustum_segments
from scenelabel.viz.viewer_gui import rotation_from_wxyz, wxyz_from_rotation

CLASSES = {1: "floor", 3: "box", 5: "chair"}


def hand_map() -> OccupancyMap:
    """A floor layer, a box on it and two UNKNOWN voxels; class 5 has no voxel. Probabilities and
    confidence are stored (a one-hot per occupied voxel)."""
    label = np.full((8, 6, 5), FREE, np.int16)
    label[:, :, 0] = 1
    label[2:4, 2:4, 1:4] = 3
    label[6:, 5, 4] = UNKNOWN
    occupancy = np.where(label >= 0, 1.0, 0.0).astype(np.float32)
    probs = np.zeros(label.shape + (3,), np.float32)
    for channel, cid in enumerate(sorted(CLASSES)):
        probs[..., channel] = label == cid
    probs[label == FREE] = 1 / 3
    confidence = np.where(label >= 0, 1.0, 0.0)
    return OccupancyMap(label, occupancy, 0.1, [0.0, 0.0, 0.0], CLASSES, 0.1, probs=probs, confidence=confidence)


@pytest.fixture()
def map_viewer():
    app = ViewerApp(hand_map())
    app.start(port=0)
    yield app
    app.stop()


@pytest.fixture(scope="module")
def tiny_build(tmp_path_factory):
    """A 20-step build of a small toy scene (its scene beside it: the frusta find the photos)."""
    from scenelabel import build, preset, write_toy_scene

    root = tmp_path_factory.mktemp("viewer")
    scene = write_toy_scene(root / "scene", n_train=7, n_test=1, width=24, height=18)
    config = preset("quick", {"train": {"steps": 20, "time_budget": None}})
    return build(scene, root / "out", config, progress=False).out_dir


def look_down(x: float, y: float, height: float) -> np.ndarray:
    """c2w (OpenCV axes) of a camera at (x, y, height) looking straight down (-z)."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.diag([1.0, -1.0, -1.0])
    c2w[:3, 3] = (x, y, height)
    return c2w


# ----------------------------------------------------------------------------------------- server side


def test_the_scene_holds_each_class_as_the_map_does(map_viewer):
    app, m = map_viewer, map_viewer.map
    assert app.url.startswith("http://127.0.0.1:") and int(app.url.rsplit(":", 1)[1]) > 0
    assert set(app.class_nodes) == {1, 3, UNKNOWN}  # chair has no voxel: no node
    assert app.shown_voxels() == {1: 48, 3: 12, UNKNOWN: 0}  # UNKNOWN starts hidden (and unsent)
    app.set_class_visible(UNKNOWN, True)
    for cid in (1, 3, UNKNOWN):
        node = app.class_nodes[cid]
        assert len(node.points) == np.count_nonzero(m.label == cid) == app.voxel_counts[cid]
        centres = m.world_from_index(np.argwhere(m.label == cid))
        np.testing.assert_allclose(np.sort(node.points, 0), np.sort(centres, 0), atol=1e-6)
        assert node.point_size == pytest.approx(m.voxel_size)
    assert tuple(app.class_nodes[3].colors) == app.palette[3]


def test_checkboxes_and_height_slider_hide_voxels(map_viewer):
    app = map_viewer
    app.set_class_visible(3, False)
    assert not app.class_nodes[3].visible and app.shown_voxels()[3] == 0 and app.shown_voxels()[1] == 48
    app.set_class_visible(3, True)
    app.set_class_visible(UNKNOWN, True)
    assert app.shown_voxels() == {1: 48, 3: 12, UNKNOWN: 2}
    app.set_height_limit(0.15)  # the floor (z = 0) and the box's first layer (z = 0.1)
    assert app.height_slider.value == pytest.approx(0.15)
    assert app.shown_voxels() == {1: 48, 3: 4, UNKNOWN: 0}
    app.set_height_limit(-1.0)  # nothing below
    assert app.shown_voxels() == {1: 0, 3: 0, UNKNOWN: 0}
    app.set_height_limit(1.0)
    assert app.shown_voxels() == {1: 48, 3: 12, UNKNOWN: 2}


def test_point_queries_answer_as_the_map(map_viewer):
    app, m = map_viewer, map_viewer.map
    points = np.array([[0.25, 0.25, 0.15], [0.0, 0.0, 0.0], [0.7, 0.1, 0.3], [0.65, 0.5, 0.4], [5.0, 5.0, 5.0]])
    for xyz in points:
        answer = app.query(xyz)
        assert answer.label == int(m.label_at(xyz[None])[0])
        assert answer.occupancy == pytest.approx(float(m.occupancy_at(xyz[None])[0]))
        assert answer.source == "map"
    box = app.query(points[0])
    assert (box.name, box.confidence) == ("box", 1.0)
    assert box.probs.tolist() == [0.0, 1.0, 0.0] and box.class_ids.tolist() == [1, 3, 5]
    assert app.query(points[3]).name == "UNKNOWN" and app.query(points[4]).name == "UNKNOWN"
    assert app.query(points[2]).name == "FREE"
    # the panel shows the same answer, and a click finds the first voxel its ray meets
    assert app.show_query(points[0]).label == 3
    assert "box (id 3)" in app.gui["query_answer"].content
    hit = app.click_point([0.32, 0.28, 2.0], [0.0, 0.0, -1.0])
    np.testing.assert_allclose(hit, [0.3, 0.3, 0.3])  # the box's top voxel under the ray
    assert app.click_point([0.32, 0.28, 2.0], [0.0, 0.0, 1.0]) is None
    with pytest.raises(InputError):
        app.query([np.nan, 0, 0])
    assert app.show_query([np.nan, 0, 0]) is None and "error" in app.gui["query_answer"].content


def test_a_view_rendered_from_the_map(map_viewer):
    app, m = map_viewer, map_viewer.map
    c2w = look_down(0.31, 0.29, 2.0)
    render = app.render_view(c2w, fov_y=0.8)
    assert render.method == "map" and render.rgb is None
    assert render.label.shape == (240, 320) and render.labels.shape == render.depth.shape == (240, 320, 3)
    centre = render.label[120, 160]
    assert centre == m.cast_rays(c2w[None, :3, 3], np.array([[0.0, 0.0, -1.0]])).label[0] == 3
    assert render.depth_values[120, 160] == pytest.approx(2.0 - 0.35, abs=1e-3)  # the top face of the box
    assert set(np.unique(render.label).tolist()) <= {1, 3, FREE, UNKNOWN}
    assert tuple(render.labels[120, 160]) == app.palette[3]
    with pytest.raises(InputError):
        app.render_view(c2w, 0.8, method="field")  # no field
    with pytest.raises(InputError):
        app.render_view(c2w, 0.8, method="photo")


def test_quaternions_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q) * np.sign(q[0])
        r = rotation_from_wxyz(q)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(wxyz_from_rotation(r), q, atol=1e-9)


def test_stop_frees_the_port_and_the_page_is_served_offline():
    app = ViewerApp(hand_map())
    url = app.start(port=0)
    with urllib.request.urlopen(url, timeout=10) as reply:
        page = reply.read().decode()
    assert "<title>Viser</title>" in page
    assert "src=\"http" not in page and "href=\"http" not in page  # no CDN: the client is bundled
    port = int(url.rsplit(":", 1)[1])
    app.stop()
    app.stop()  # idempotent
    with socket.socket() as s:
        assert s.connect_ex(("127.0.0.1", port)) != 0


def test_a_build_is_shown_with_its_field_and_cameras(tiny_build):
    from scenelabel.query.field import SemanticField

    app = ViewerApp.open(tiny_build)
    field = SemanticField.load(tiny_build)
    assert app.field is not None and app.cameras is not None
    assert app.view_images is not None and all(im is not None and im.shape[2] == 3 for im in app.view_images)
    app.start(port=0)
    try:
        n_cameras = len(field.training_cameras())
        assert app.frustum_nodes[0].points.shape == (10 * n_cameras, 2, 3)  # every frustum in one node
        assert len(app.frustum_nodes) == 1 + n_cameras  # and each photo on its frustum
        app.set_class_visible(UNKNOWN, True)
        for cid, node in app.class_nodes.items():
            assert len(node.points) == np.count_nonzero(app.map.label == cid)
        lo, hi = field.aabb
        rng = np.random.default_rng(1)
        points = np.vstack([lo + (hi - lo) * rng.random((20, 3)), [hi + 1.0]])
        expected = field.query_points(points)
        for i, xyz in enumerate(points):
            answer = app.query(xyz)
            assert answer.source == "field" and answer.label == expected.label[i]
            np.testing.assert_allclose(answer.probs, expected.probs[i])
            assert answer.occupancy == pytest.approx(expected.occupancy[i])
        # a click: the field's surface under the ray (or the centre of the map's voxel there)
        click = app.click_point([0.0, 0.0, hi[2] + 1.0], [0.0, 0.0, -1.0])
        if click is not None:  # (a 20-step field may see through)
            assert lo[2] <= click[2] <= hi[2] and np.abs(click[:2]).max() <= app.map.voxel_size / 2 + 1e-9
        c2w = look_down(0.0, 0.0, 3.0)
        for method in ("field", "baked", "map"):
            render = app.render_view(c2w, 0.9, size=(64, 48), method=method)
            assert render.label.shape == (48, 64) and (render.rgb is not None) == (method == "field")
        app.gui["meshes"].value = True  # the class meshes, made on first use
        assert set(app.mesh_nodes) <= set(app.map.classes) and all(node.visible for node in app.mesh_nodes.values())
    finally:
        app.stop()


def test_a_build_served_before_its_field_is_loaded(tiny_build):
    """``open(field_later=True)`` serves the build's own map at once; load_field adds the field's
    cameras, panels and answers (what ``scenelabel view`` does while the page opens)."""
    app = ViewerApp.open(tiny_build, field_later=True)
    assert app.field is None and app.cameras is None
    now = ViewerApp.open(tiny_build)
    np.testing.assert_array_equal(app.map.label, now.map.label)
    app.start(port=0)
    try:
        assert not app.frustum_nodes and "query_button" not in app.gui  # the map alone so far
        assert app.load_field() and not app.load_field()  # loaded once
        assert app.field is not None and app.palette == now.palette
        assert len(app.frustum_nodes) == 1 + len(app.cameras) and "query_button" in app.gui
        xyz = np.mean(app.field.aabb, axis=0)
        assert app.query(xyz).source == "field" and app.query(xyz).label == now.query(xyz).label
    finally:
        app.stop()


def test_frustum_segments_outline_the_image():
    """The rectangle's corners lie on the rays of the image corners, at the depth that gives the
    pyramid viser's volume for the scale; the four edges start at the camera centre."""
    w, h, f = 160, 120, 150.0
    c2w = np.eye(4)
    c2w[:3, :3] = rotation_from_wxyz(np.array([0.9, 0.1, -0.3, 0.2]))
    c2w[:3, 3] = (1.0, -2.0, 0.5)
    fov = 2 * np.arctan(0.5 * h / f)
    segments, (half_w, half_h, depth) = frustum_segments(c2w, fov, w / h, 0.3)
    assert segments.shape == (10, 2, 3)
    np.testing.assert_allclose(segments[:4, 0], np.tile(c2w[:3, 3], (4, 1)), atol=1e-6)
    local = (segments[:4, 1] - c2w[:3, 3]) @ c2w[:3, :3]  # corners in the camera frame
    pixels = local[:, :2] / local[:, 2:] * f + [w / 2, h / 2]
    np.testing.assert_allclose(pixels, [[0, 0], [w, 0], [w, h], [0, h]], atol=1e-3)
    np.testing.assert_allclose(local[:, 2], depth, rtol=1e-6)
    assert half_w * half_h * depth / 3 == pytest.approx(0.3**3)


def test_open_refuses_what_it_cannot_show(tmp_path, tiny_build):
    with pytest.raises(InputError, match="neither a build folder"):
        ViewerApp.open(tmp_path)
    path = hand_map().to_zarr(tmp_path / "m.zarr")
    with pytest.raises(InputError, match="voxel size"):
        ViewerApp.open(path, voxel_size=0.2)
    assert ViewerApp.open(path).field is None


def test_view_command_serves_a_build_and_then_loads_its_field(tiny_build):
    proc = subprocess.run(
        [sys.executable, "-m", "scenelabel", "view", str(tiny_build), "--port", "0", "--timeout", "1"],
        capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert " at http://127.0.0.1:" in lines[0] and "field loaded" in lines[1]


def test_view_command_serves_until_its_timeout(tmp_path):
    path = hand_map().to_zarr(tmp_path / "m.zarr")
    proc = subprocess.run(
        [sys.executable, "-m", "scenelabel", "view", str(path), "--port", "0", "--timeout", "1"],
        capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "http://127.0.0.1:" in proc.stdout
    command = [sys.executable, "-m", "scenelabel", "view", str(tmp_path / "nothing")]
    proc = subprocess.run(command, capture_output=True, text=True, check=False)
    assert proc.returncode == 2 and "neither a build folder" in proc.stderr


# ----------------------------------------------------------------------------------------- a real browser


PRESS_BUTTON = """(() => {
  const button = [...document.querySelectorAll('button')].find(b => b.textContent.trim() === '%s');
  if (button) button.click();
  return Boolean(button);
})()"""


def test_colour_fraction_counts_the_pixels_near_a_colour():
    image = np.zeros((4, 10, 3), np.uint8)
    image[:, :5] = (200, 30, 30)
    image[0, 5] = (210, 40, 45)  # within 40 (the sum of the channels' differences) of red
    assert colour_fraction(image, (200, 30, 30)) == 21 / 40
    assert colour_fraction(image, (200, 30, 30), tolerance=0) == 20 / 40
    assert colour_fraction(image, (0, 0, 0)) == 19 / 40


@pytest.mark.skipif(find_chromium() is None, reason="no chromium binary (Debian: apt-get install chromium)")
def test_a_headless_browser_shows_the_map_in_its_class_colours(map_viewer, tmp_path):
    app = map_viewer
    with HeadlessBrowser(800, 600) as browser:
        browser.open(app.url)
        client = app.wait_for_client(60)
        colours = [app.palette[1], app.palette[3]]
        try:
            image = browser.wait_for(lambda im: all(colour_fraction(im, c) > 0.003 for c in colours), timeout=60)
        except TimeoutError as err:
            from PIL import Image

            Image.fromarray(err.image).save(tmp_path / "viewer.png")
            raise AssertionError(f"the map's colours never showed: see {tmp_path / 'viewer.png'}") from err
        assert image.shape == (600, 800, 3) and image.std() > 10  # not a blank canvas
        # the floor (48 voxels) covers more of the picture than the box (12, on top of it)
        assert colour_fraction(image, app.palette[1]) > colour_fraction(image, app.palette[3]) > 0.003
        assert colour_fraction(image, app.palette[5]) < 0.001  # chair: no voxel
        app.set_class_visible(3, False)
        browser.wait_for(lambda im: colour_fraction(im, app.palette[3]) < 0.0005, timeout=30)
        # "Render this view" from the browser's own camera: the map seen as the browser sees it
        render = app.show_render(client)
        assert colour_fraction(render.labels, app.palette[1]) > 0.003
        assert app.gui["render_labels"].visible and not app.gui["render_rgb"].visible
        # the page's own buttons reach the app: pressed in the browser, answered by the server
        app.last_render = app.last_answer = None
        for text in ("Query point", "Render this view"):
            assert browser.evaluate(PRESS_BUTTON % text), text
        deadline = time.monotonic() + 60
        while (app.last_render is None or app.last_answer is None) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert app.last_answer is not None and app.last_answer.source == "map"
        assert app.last_render is not None and app.last_render.method == "map"
        assert "from the map" in app.gui["query_answer"].content
