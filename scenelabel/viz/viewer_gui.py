"""The web viewer's panels (viser GUI) and the browser camera's pose; the viewer itself is
:class:`scenelabel.viz.viewer.ViewerApp`, whose public methods every panel calls.

Panels: "Map" (a checkbox per class and for UNKNOWN, the height slider, the training cameras, the
class meshes), "Query" (a point typed or clicked -> label, class probabilities, confidence,
occupancy) and "Render" (the browser camera rendered by the field, the baked field or the map).
Work that may last over a second shows a notification in the browser while it runs.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from scenelabel.maps import UNKNOWN

__all__ = ["add_panels", "camera_pose", "rotation_from_wxyz", "wxyz_from_rotation", "class_mesh_arrays", "progress"]

MARKER_COLOR = (255, 0, 255)
"""The queried point's marker."""


# ----------------------------------------------------------------------------------------- poses


def rotation_from_wxyz(wxyz: Any) -> np.ndarray:
    """[4] unit quaternion (w, x, y, z) -> [3, 3] rotation matrix."""
    w, x, y, z = np.asarray(wxyz, np.float64) / np.linalg.norm(wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def wxyz_from_rotation(rotation: Any) -> np.ndarray:
    """[3, 3] rotation matrix -> [4] unit quaternion (w, x, y, z) with w >= 0."""
    m = np.asarray(rotation, np.float64)
    # of 4w², 4x², 4y², 4z² the largest gives the best-conditioned formula
    cases = [np.trace(m), m[0, 0] - m[1, 1] - m[2, 2], m[1, 1] - m[0, 0] - m[2, 2], m[2, 2] - m[0, 0] - m[1, 1]]
    k = int(np.argmax(cases))
    s = 2.0 * math.sqrt(max(1.0 + cases[k], 1e-12))
    if k == 0:
        q = [s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        q = [(m[2, 1] - m[1, 2]) / s, s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s]
    else:
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4]
    q = np.asarray(q) / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def camera_pose(camera: Any) -> tuple[np.ndarray, float]:
    """A browser camera as a render needs it.

    Args:
        camera: viser's ``CameraHandle`` (OpenCV axes: ``wxyz`` and ``position`` of
            camera-to-world, vertical ``fov`` in radians).
    Returns:
        [4, 4] float64 c2w (OpenCV axes), vertical field of view in radians.
    """
    c2w = np.eye(4)
    c2w[:3, :3] = rotation_from_wxyz(camera.wxyz)
    c2w[:3, 3] = np.asarray(camera.position, np.float64)
    return c2w, float(camera.fov)


# ----------------------------------------------------------------------------------------- helpers


@contextlib.contextmanager
def progress(client: Any, title: str, body: str) -> Iterator[None]:
    """A loading notification in ``client``'s browser while the block runs, then how long it took
    (or the error, which is not raised further: a GUI callback has nowhere to raise to). No
    client (a call from Python): the block just runs, and errors are raised."""
    if client is None:
        yield
        return
    note = client.add_notification(title, body, loading=True, with_close_button=False)
    start = time.perf_counter()
    try:
        yield
    except Exception as err:  # shown to the user in the browser
        note.title, note.body, note.color = f"{title}: failed", str(err), "red"
        note.loading, note.with_close_button = False, True
    else:
        note.title, note.body = title, f"done in {time.perf_counter() - start:.1f} s"
        note.loading, note.with_close_button, note.auto_close_seconds = False, True, 4.0


def class_mesh_arrays(occ_map: Any) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per class (vertices [V, 3] float32, faces [F, 3] uint32) of the map's class meshes
    (:func:`scenelabel.maps.exports.class_meshes`)."""
    from scenelabel.maps.exports import class_meshes

    return {
        int(cid): (mesh.vertices.astype(np.float32), mesh.faces.astype(np.uint32))
        for cid, mesh in class_meshes(occ_map).items()
    }


def _swatch(color: tuple[int, int, int]) -> str:
    return f"<span style='color:rgb{tuple(color)}'>&#9632;</span>"


# ----------------------------------------------------------------------------------------- panels


def add_panels(app: Any, server: Any) -> None:
    """Add the "Map", "Query" and "Render" panels of ``app`` (a ViewerApp) to a viser server."""
    _map_panel(app, server)
    _query_panel(app, server)
    _render_panel(app, server)


def _map_panel(app: Any, server: Any) -> None:
    m = app.map
    gui = server.gui
    with gui.add_folder("Map"):
        lo, hi = m.bounds
        source = "build (field + map)" if app.field is not None else "map"
        legend = " ".join(f"{_swatch(app.palette[c])} {app.classes[c]}" for c in app.palette)
        gui.add_html(
            f"<div style='font-size:0.8em'>{source}, voxel {m.voxel_size:.3g}, {' x '.join(map(str, m.shape))} voxels"
            f"<br>{legend}</div>"
        )
        for cid, node in app.class_nodes.items():
            count = app.voxel_counts[cid]
            name = "UNKNOWN" if cid == UNKNOWN else f"{app.classes[cid]} ({cid})"
            box = gui.add_checkbox(f"{name}: {count:,}", node.visible, hint=f"show the {name} voxels")
            box.on_update(lambda _event: app.refresh_nodes())
            app.class_checkboxes[cid] = box
        z_lo, z_hi = math.floor(float(lo[2]) * 1000) / 1000, math.ceil(float(hi[2]) * 1000) / 1000
        slider = gui.add_slider(
            "show below z", z_lo, z_hi, m.voxel_size, z_hi, hint="voxels whose centre is at or below this height"
        )
        slider.on_update(lambda event: app.refresh_nodes(float(event.target.value)))
        app.height_slider = slider
        if app.frustum_nodes:
            frusta = gui.add_checkbox(f"training cameras ({len(app.cameras)})", True)

            @frusta.on_update
            def _(event: Any) -> None:
                for node in app.frustum_nodes:
                    node.visible = bool(event.target.value)

        meshes = gui.add_checkbox("class meshes", False, hint="the surface of each class (made on first use)")
        app.gui["meshes"] = meshes

        @meshes.on_update
        def _(event: Any) -> None:
            if event.target.value and not app.mesh_nodes:
                with progress(event.client, "Meshes", "meshing the map's classes"):
                    for cid, (verts, faces) in class_mesh_arrays(m).items():
                        color = app.palette.get(cid, (200, 200, 200))
                        node = server.scene.add_mesh_simple(f"/meshes/class_{cid}", verts, faces, color=color)
                        app.mesh_nodes[cid] = node
            for node in app.mesh_nodes.values():
                node.visible = bool(event.target.value)


def _query_panel(app: Any, server: Any) -> None:
    gui = server.gui
    lo, hi = app.map.bounds
    with gui.add_folder("Query"):
        point = gui.add_vector3("x, y, z", tuple(float(v) for v in (lo + hi) / 2), step=0.001)
        button = gui.add_button("Query point", hint="or click a voxel in the scene")
        answer = gui.add_markdown("Type a point and press *Query point*, or click a voxel.")
    app.gui.update(query_point=point, query_button=button, query_answer=answer)
    button.on_click(lambda _event: app.show_query(np.asarray(point.value, np.float64)))

    @server.scene.on_click()
    def _(event: Any) -> None:
        hit = app.click_point(event.ray_origin, event.ray_direction)
        if hit is None:
            event.client.add_notification("Query", "the click's ray meets no occupied voxel", auto_close_seconds=3.0)
        else:
            app.show_query(hit)


def _render_panel(app: Any, server: Any) -> None:
    gui = server.gui
    methods = ("field", "baked", "map") if app.field is not None else ("map",)
    with gui.add_folder("Render", expand_by_default=True):
        method = gui.add_dropdown(
            "method", methods, initial_value=methods[0],
            hint="field: rgb, labels, depth; baked: labels, depth from a lattice (baked once); "
            "map: labels, depth of the voxels",
        )
        button = gui.add_button("Render this view", hint="the browser camera at 320 x 240")
        images = {
            key: gui.add_image(np.full((24, 32, 3), 255, np.uint8), label=key, visible=False)
            for key in ("rgb", "labels", "depth")
        }
    app.gui.update(render_method=method, render_button=button, **{f"render_{k}": v for k, v in images.items()})

    @button.on_click
    def _(event: Any) -> None:
        if event.client is not None:
            with progress(event.client, "Render", f"{method.value}: 320 x 240 from this view"):
                app.show_render(event.client)
