"""The web viewer (``scenelabel view BUILD | MAP.zarr``): a map, its training cameras and its field in
a browser, served by viser on this machine.

- the map's occupied voxels as one point cloud of voxel-sized squares per class, in the class
  colours (:func:`~scenelabel.maps.exports.palette.class_palette`), a checkbox per class and one for
  UNKNOWN, a height slider (voxels whose centre lies below z);
- with a build: the training cameras as frusta (with their photos when the scene's images are
  found), the per-class meshes on demand, a point query (typed or clicked) answered by the field,
  and "render this view": the browser camera's pose rendered at 320 x 240 by the field (rgb,
  labels, depth), the baked field (labels, depth) or the map (labels, depth);
- without a build (a map .zarr): the same from the map alone.

:class:`ViewerApp` is the whole viewer as an object: the GUI calls its public methods
(:meth:`ViewerApp.query`, :meth:`ViewerApp.render_view`, ...), so a script or a test gets the
answers the panels show. viser is imported only when a viewer starts.
"""

from __future__ import annotations

import contextlib
import io
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from scenelabel.codes import CODE_NAMES
from scenelabel.errors import InputError
from scenelabel.maps import FREE, UNKNOWN, OccupancyMap, confidence_from_probs, unit_from_uint8
from scenelabel.maps.exports.palette import class_palette, color_lookup
from scenelabel.query.build_outputs import own_map
from scenelabel.viz.viewer_cameras import find_view_images, frustum_segments, view_image_candidates
from scenelabel.viz.viewer_gui import MARKER_COLOR, add_panels, camera_pose, wxyz_from_rotation

if TYPE_CHECKING:
    from scenelabel.geometry.cameras import Cameras
    from scenelabel.query.baked import BakedField
    from scenelabel.query.field import SemanticField

__all__ = [
    "ViewerApp",
    "PointAnswer",
    "ViewRender",
    "DEFAULT_PORT",
    "DEFAULT_HOST",
    "RENDER_SIZE",
    "RENDER_METHODS",
    "UNKNOWN_COLOR",
    "BACKGROUND_COLOR",
    "MAX_POINTS",
    "find_view_images",
    "view_image_candidates",
    "frustum_segments",
]

DEFAULT_PORT = 8080
DEFAULT_HOST = "127.0.0.1"
RENDER_SIZE = (320, 240)
"""(width, height) of "render this view"."""
RENDER_METHODS = ("field", "baked", "map")
"""What renders a view: the field (rgb, labels, depth), the baked field or the map (labels, depth)."""
UNKNOWN_COLOR = (150, 150, 150)
"""UNKNOWN voxels in the scene and in rendered label images."""
BACKGROUND_COLOR = (255, 255, 255)
"""Pixels whose ray met nothing (FREE) in rendered label and depth images."""
MAX_POINTS = 2_000_000
"""At most this many voxels of one class (or UNKNOWN) go to the browser; more are thinned evenly."""


# ----------------------------------------------------------------------------------------- answers


@dataclass(frozen=True)
class PointAnswer:
    """What the viewer says about one world point (the "Query" panel).

    Attributes:
        xyz: [3] float64 world point.
        label: class id, FREE (-1) or UNKNOWN (-2).
        name: the class name, "FREE" or "UNKNOWN".
        occupancy: 1 - exp(-σ δ) at the point (field) or of its voxel (map).
        probs: [C] float64 class probabilities over ``class_ids`` (zeros: a map without probs,
            or UNKNOWN).
        class_ids: [C] int64 class ids.
        confidence: 1 - H(p) / log C in [0, 1]; NaN when the map stores no confidence.
        source: "field" (the field's ``query_points``) or "map" (the voxel holding the point).
    """

    xyz: np.ndarray
    label: int
    name: str
    occupancy: float
    probs: np.ndarray
    class_ids: np.ndarray
    confidence: float
    source: str

    def markdown(self, classes: dict[int, str], top: int = 5) -> str:
        """The answer as the panel shows it (markdown): the point, label, occupancy, confidence and
        the ``top`` most probable classes."""
        x, y, z = (float(v) for v in self.xyz)
        conf = "n/a" if math.isnan(self.confidence) else f"{self.confidence:.3f}"
        label = self.name if self.label < 0 else f"{self.name} (id {self.label})"
        lines = [
            f"**({x:.3f}, {y:.3f}, {z:.3f})** from the {self.source}",
            "",
            f"label: **{label}**  ",
            f"occupancy: {self.occupancy:.3f}, confidence: {conf}",
        ]
        if self.probs.size and self.probs.sum() > 0:
            lines += ["", "| class | p |", "|---|---|"]
            for c in np.argsort(-self.probs, kind="stable")[:top].tolist():
                cid = int(self.class_ids[c])
                lines.append(f"| {classes.get(cid, str(cid))} | {self.probs[c]:.3f} |")
        return "\n".join(lines)


@dataclass(frozen=True)
class ViewRender:
    """One camera rendered for the "Render" panel.

    Attributes:
        rgb: [H, W, 3] uint8 colour, or None (the baked field and the map hold no colour).
        labels: [H, W, 3] uint8 class colours (UNKNOWN grey, nothing hit white).
        depth: [H, W, 3] uint8 depth colour-mapped (near bright), white where nothing was hit.
        label: [H, W] int class ids, FREE or UNKNOWN.
        depth_values: [H, W] float64 distance along each pixel's unit ray, world units; inf: no hit.
        method: one of :data:`RENDER_METHODS`.
        seconds: how long rendering took.
    """

    rgb: np.ndarray | None
    labels: np.ndarray
    depth: np.ndarray
    label: np.ndarray
    depth_values: np.ndarray
    method: str
    seconds: float


def _depth_colors(depth: np.ndarray) -> np.ndarray:
    """[H, W] depths -> [H, W, 3] uint8: near bright yellow to far dark purple (matplotlib's
    magma, reversed), white where the depth is not finite."""
    from matplotlib import colormaps

    finite = np.isfinite(depth)
    out = np.full(depth.shape + (3,), BACKGROUND_COLOR, np.uint8)
    if finite.any():
        lo, hi = np.percentile(depth[finite], [1, 99])
        t = np.clip((depth[finite] - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
        out[finite] = (colormaps["magma"](0.95 - 0.85 * t)[:, :3] * 255).astype(np.uint8)
    return out


def _build_field(
    source: Path, images: str | Path | None, device: str | None
) -> tuple["SemanticField", list[np.ndarray | None] | None]:
    """A build folder's field and its training views' photos (None when they are not found)."""
    from scenelabel.query.field import SemanticField

    field = SemanticField.load(source, device)
    names = list(field.meta.get("train_views") or [])
    cameras = field.training_cameras()
    found = cameras is not None and len(names) == len(cameras)
    return field, (find_view_images(view_image_candidates(source, field.meta, names, images)) if found else None)


# ----------------------------------------------------------------------------------------- the app


class ViewerApp:
    """A map (and optionally the field that made it) shown in the browser.

    Args:
        occ_map: the map to show.
        field: the build's field (point queries, renders, cameras), or None (a map alone).
        view_images: per training camera its photo or None (see :func:`find_view_images`).
        title: shown at the top of the GUI panel.

    ``start()`` serves it and returns the URL; ``stop()`` ends it. Without a browser every answer
    is a method: :meth:`query`, :meth:`render_view`, :meth:`set_class_visible`,
    :meth:`set_height_limit`, :meth:`shown_voxels`.
    """

    def __init__(
        self,
        occ_map: OccupancyMap,
        field: "SemanticField | None" = None,
        view_images: list[np.ndarray | None] | None = None,
        title: str = "scenelabel",
    ):
        self.map = occ_map
        self.title = title
        self.field: SemanticField | None = None
        self.cameras: Cameras | None = None
        self.view_images: list[np.ndarray | None] | None = None
        self._set_field(field, view_images)
        self.server: Any = None
        self.url: str | None = None
        self.class_nodes: dict[int, Any] = {}  # class id (or UNKNOWN) -> point cloud handle
        self.class_checkboxes: dict[int, Any] = {}
        self.frustum_nodes: list[Any] = []  # the frusta's line node, then one image node per photo
        self.mesh_nodes: dict[int, Any] = {}
        self.height_slider: Any = None
        self.gui: dict[str, Any] = {}
        self.last_answer: PointAnswer | None = None
        self.last_render: ViewRender | None = None
        self._baked: BakedField | None = None
        self._lock = threading.Lock()  # baking
        self._scene_lock = threading.RLock()  # the point clouds
        self._sent: dict[int, int] = {}  # class id -> how many points its cloud holds in the browser
        self._pending_field: tuple[Path, Path | None, str | None] | None = None  # open(..., field_later=True)
        self._extent = 1.0  # the diagonal of the occupied voxels' box (sizes the frusta)
        self._centres = self._voxel_centres()
        self.voxel_counts = {cid: int(np.count_nonzero(occ_map.label == cid)) for cid in self._centres}
        """Class id (and UNKNOWN) -> its voxels in the map (the scene shows at most MAX_POINTS of them)."""
        self._height = float(occ_map.bounds[1][2])

    def _set_field(self, field: "SemanticField | None", view_images: list[np.ndarray | None] | None) -> None:
        """The field, its classes and colours (beside the map's) and its training cameras."""
        self.field = field
        self.classes = dict(self.map.classes)
        colors = dict(self.map.class_colors or {})
        if field is not None:
            self.classes.update(field.classes)
            colors.update(field.meta.get("class_colors") or {})
        self.palette = class_palette(self.classes, {k: v for k, v in colors.items() if k in self.classes})
        self.cameras = None if field is None else field.training_cameras()
        self.view_images = view_images

    # ------------------------------------------------------------------ construction
    @classmethod
    def open(cls, source: str | Path, voxel_size: float | None = None, images: str | Path | None = None,
             device: str | None = None, field_later: bool = False) -> "ViewerApp":
        """A viewer of a build folder (its field, its map, its cameras) or of a map ``.zarr``.

        Args:
            source: a build folder (with checkpoint.pt) or an occupancy map (.zarr folder).
            voxel_size: for a build: the map's voxel size (default: the build's own map.zarr when it
                is at least as new as the checkpoint, else the field's default voxel size).
            images: folder of the scene's photos for the frusta (default: looked for beside the build).
            device: 'cpu' or 'cuda' for the field (default: the best).
            field_later: for a build whose own map serves: open with the map alone and leave the
                field (torch, the checkpoint) to :meth:`load_field`, so that the map can be served
                first (``scenelabel view``); otherwise the field is loaded now.
        Raises:
            InputError: neither a build folder nor a map; ``voxel_size`` with a map.
        """
        source = Path(source)
        if (source / "checkpoint.pt").is_file():
            name = source.resolve().name
            name = source.resolve().parent.name if name == "scenelabel" else name  # SCENE/scenelabel: the scene
            occ = own_map(source, voxel_size)
            if field_later and occ is not None:
                app = cls(occ, title=f"scenelabel: {name}")
                app._pending_field = (source, None if images is None else Path(images), device)
                return app
            field, view_images = _build_field(source, images, device)
            return cls(occ or field.occupancy_map(voxel_size), field, view_images, title=f"scenelabel: {name}")
        if source.is_dir() and ((source / "zarr.json").is_file() or (source / ".zgroup").is_file()):
            if voxel_size is not None:
                raise InputError("--voxel-size applies to a build folder; a map keeps its own voxel size", path=source)
            return cls(OccupancyMap.from_zarr(source), title=f"scenelabel: {source.name}")
        raise InputError("neither a build folder (with checkpoint.pt) nor an occupancy map (.zarr folder)", path=source)

    @property
    def field_pending(self) -> bool:
        """Whether ``open(..., field_later=True)`` left a field for :meth:`load_field`."""
        return self._pending_field is not None

    def load_field(self) -> bool:
        """Load the field an ``open(..., field_later=True)`` left for later, and, when serving, add
        what needs it: the training cameras and the panels (queries and renders by the field).
        Returns whether a field was loaded (False: none was pending)."""
        if self._pending_field is None:
            return False
        source, images, device = self._pending_field
        field, view_images = _build_field(source, images, device)
        self._pending_field = None
        self._set_field(field, view_images)  # the build's own map: the same classes and colours
        if self.server is not None:
            self._add_frusta(self.server)
            add_panels(self, self.server)
        return True

    def _voxel_centres(self) -> dict[int, np.ndarray]:
        """Class id (and UNKNOWN) -> [n, 3] float32 centres of its voxels, thinned to MAX_POINTS."""
        label = self.map.label
        out = {}
        for cid in [*sorted(self.palette), UNKNOWN]:
            ijk = np.argwhere(label == cid)
            if len(ijk) > MAX_POINTS:
                ijk = ijk[np.linspace(0, len(ijk) - 1, MAX_POINTS).astype(np.int64)]
            if cid >= 0 and not len(ijk):
                continue
            out[cid] = self.map.world_from_index(ijk).astype(np.float32)
        return out

    # ------------------------------------------------------------------ answers
    def class_name(self, label: int) -> str:
        """A label's name: the class name, "FREE" or "UNKNOWN"."""
        return CODE_NAMES.get(int(label)) or self.classes.get(int(label), str(int(label)))

    def query(self, xyz: Any) -> PointAnswer:
        """What is at a world point: the field's ``query_points`` when a field is loaded, else the
        voxel of the map that holds it. The "Query" panel shows exactly this.

        Args:
            xyz: [3] world point.
        Returns:
            PointAnswer.
        """
        xyz = np.asarray(xyz, np.float64).reshape(3)
        if not np.isfinite(xyz).all():
            raise InputError(f"a point needs three finite numbers, got {xyz.tolist()}", field="xyz")
        if self.field is not None:
            q = self.field.query_points(xyz[None])
            probs = np.asarray(q.probs[0], np.float64)
            answer = PointAnswer(xyz, int(q.label[0]), self.class_name(q.label[0]), float(q.occupancy[0]), probs,
                                 np.asarray(q.class_ids), float(confidence_from_probs(probs)), "field")
        else:
            m = self.map
            idx, inside = m.index_from_world(xyz[None])
            label = int(m.label_at(xyz[None])[0])
            probs = np.zeros(len(m.classes))
            confidence = math.nan
            if inside[0]:
                voxel = tuple(idx[0])
                if m.probs is not None:
                    probs = unit_from_uint8(m.probs[voxel]).astype(np.float64)
                if m.confidence is not None:
                    confidence = float(unit_from_uint8(m.confidence[voxel]))
            answer = PointAnswer(xyz, label, self.class_name(label), float(m.occupancy_at(xyz[None])[0]), probs,
                                 m.class_ids, confidence, "map")
        self.last_answer = answer
        return answer

    def click_point(self, origin: Any, direction: Any) -> np.ndarray | None:
        """The point a click's ray (world origin and direction) picks: with a field, the surface
        its ray meets (at the ray's depth: a field is dense at surfaces, often not inside objects);
        without one, or when the field's ray meets nothing, the centre of the first occupied map
        voxel it enters. None when it meets nothing."""
        origins = np.asarray(origin, np.float64).reshape(1, 3)
        directions = np.asarray(direction, np.float64).reshape(1, 3)
        directions = directions / np.linalg.norm(directions)
        if self.field is not None:
            ray = self.field.query_rays(origins, directions, with_rgb=False)
            if ray.label[0] >= 0 and np.isfinite(ray.depth[0]):
                return origins[0] + ray.depth[0] * directions[0]
        hit = self.map.cast_rays(origins, directions)
        if not np.isfinite(hit.depth[0]) or hit.label[0] < 0:
            return None
        return self.map.world_from_index(hit.index[:1])[0]

    def baked(self) -> "BakedField":
        """The field baked once (:meth:`BakedField.from_field`, seconds), for fast label and depth renders."""
        if self.field is None:
            raise InputError("no field: a map alone renders with method 'map'", field="method")
        with self._lock:
            if self._baked is None:
                from scenelabel.query.baked import BakedField

                self._baked = BakedField.from_field(self.field)
        return self._baked

    def render_view(
        self, c2w: Any, fov_y: float, size: tuple[int, int] = RENDER_SIZE, method: str | None = None
    ) -> ViewRender:
        """Render a pinhole camera: the "Render this view" panel.

        Args:
            c2w: [4, 4] camera-to-world, OpenCV axes (the browser's camera:
                :func:`~scenelabel.viz.viewer_gui.camera_pose`).
            fov_y: vertical field of view, radians.
            size: (width, height) in pixels.
            method: "field" (rgb, labels, depth; the default with a field), "baked" (labels and
                depth from :meth:`baked`) or "map" (labels and depth cast through the map; the
                default without a field).
        Returns:
            ViewRender.
        """
        from scenelabel.geometry.rays import camera_directions_from_pixels, pixel_grid

        method = method or ("field" if self.field is not None else "map")
        if method not in RENDER_METHODS:
            raise InputError(f"method must be one of {list(RENDER_METHODS)}, got {method!r}", field="method")
        if method != "map" and self.field is None:
            raise InputError(f"method {method!r} needs a build's field; this viewer shows a map alone", field="method")
        width, height = int(size[0]), int(size[1])
        focal = 0.5 * height / math.tan(0.5 * float(fov_y))
        c2w = np.asarray(c2w, np.float64)
        start = time.perf_counter()
        rgb = None
        if method == "field":
            out = self.field.render(c2w, width, height, focal)
            rgb = (np.clip(out.rgb, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
            label, depth = out.label, np.where(out.opacity >= 0.5, out.depth, np.inf)
        else:
            dirs = camera_directions_from_pixels(pixel_grid(width, height), focal, focal, width / 2, height / 2)
            directions = dirs @ c2w[:3, :3].T
            origins = np.broadcast_to(c2w[:3, 3], directions.shape)
            source = self.baked().query_rays if method == "baked" else self.map.cast_rays
            hits = source(origins, directions)
            label, depth = hits.label, hits.depth
        label = np.asarray(label).reshape(height, width)
        depth = np.asarray(depth, np.float64).reshape(height, width)
        seconds = time.perf_counter() - start
        labels = self.label_colors(label)
        labels[~np.isfinite(depth)] = BACKGROUND_COLOR  # nothing met (FREE, or outside the map)
        render = ViewRender(rgb, labels, _depth_colors(depth), label, depth, method, seconds)
        self.last_render = render
        return render

    def show_query(self, xyz: Any) -> PointAnswer | None:
        """Answer a point in the "Query" panel (and mark it in the scene), as its button does.

        Returns:
            the answer, or None when the point was refused (the panel then says why).
        """
        try:
            answer = self.query(xyz)
        except InputError as err:
            self.gui["query_answer"].content = f"**error:** {err}"
            return None
        self.gui["query_point"].value = tuple(float(v) for v in answer.xyz)
        self.gui["query_answer"].content = answer.markdown(self.classes)
        self.server.scene.add_icosphere(
            "/query/marker", radius=1.5 * self.map.voxel_size, color=MARKER_COLOR, position=tuple(answer.xyz)
        )
        return answer

    def show_render(self, client: Any = None, method: str | None = None) -> ViewRender:
        """Render a browser's current view into the "Render" panel, as its button does.

        Args:
            client: viser's client handle (default: the first browser connected).
            method: see :meth:`render_view` (default: the panel's choice).
        """
        client = client or self.wait_for_client(0.0)
        c2w, fov = camera_pose(client.camera)
        result = self.render_view(c2w, fov, method=method or self.gui["render_method"].value)
        for key in ("rgb", "labels", "depth"):
            image, handle = getattr(result, key), self.gui[f"render_{key}"]
            if image is not None:
                handle.image = image
            handle.visible = image is not None
        return result

    def label_colors(self, label: np.ndarray) -> np.ndarray:
        """[...] labels -> [..., 3] uint8: class colours, UNKNOWN grey, FREE white."""
        palette = {**self.palette, FREE: BACKGROUND_COLOR, UNKNOWN: UNKNOWN_COLOR}
        label = np.asarray(label)
        known = np.isin(label, list(palette))
        out = np.full(label.shape + (3,), UNKNOWN_COLOR, np.uint8)
        out[known] = color_lookup(palette, label[known].astype(np.int64))
        return out

    # ------------------------------------------------------------------ what is shown
    def shown_voxels(self) -> dict[int, int]:
        """Class id (UNKNOWN for UNKNOWN) -> how many of its voxels the scene shows now (0 when hidden)."""
        return {cid: (len(node.points) if node.visible else 0) for cid, node in self.class_nodes.items()}

    def set_class_visible(self, class_id: int, visible: bool) -> None:
        """Tick or clear a class's checkbox (UNKNOWN: the UNKNOWN one), as a click does."""
        self.class_checkboxes[int(class_id)].value = bool(visible)

    def set_height_limit(self, z: float) -> None:
        """Show only voxels whose centre lies at or below world height ``z`` (moves the height slider)."""
        if self.height_slider is not None and self.height_slider.value != float(z):
            self.height_slider.value = float(z)  # its callback calls refresh_nodes
        else:
            self.refresh_nodes(float(z))

    def refresh_nodes(self, height: float | None = None) -> None:
        """Bring the point clouds in line with the checkboxes and the height limit (``height``:
        a new limit, world z). A hidden cloud's points are sent to the browser only once it is
        shown (UNKNOWN, often the largest, costs nothing until ticked)."""
        with self._scene_lock:
            if height is not None:
                self._height = float(height)
            for cid, node in self.class_nodes.items():
                checkbox = self.class_checkboxes.get(cid)
                ticked = bool(checkbox.value) if checkbox is not None else cid != UNKNOWN
                centres = self._centres[cid]
                shown = centres[centres[:, 2] <= self._height + 1e-6 * self.map.voxel_size] if ticked else centres[:0]
                if len(shown) and self._sent.get(cid) != len(shown):  # the same count: the same voxels
                    node.points = shown
                    self._sent[cid] = len(shown)
                node.visible = bool(len(shown))

    # ------------------------------------------------------------------ server
    def start(self, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST, quiet: bool = True) -> str:
        """Serve the viewer (viser) and return its URL; ``port=0`` picks a free port.

        Args:
            port: TCP port (viser tries the next ones when it is taken).
            host: interface to listen on (default: this machine only).
            quiet: hide viser's own banner.
        Returns:
            "http://HOST:PORT".
        """
        import viser

        if self.server is not None:
            return self.url or ""
        with contextlib.redirect_stdout(io.StringIO()) if quiet else contextlib.nullcontext():
            server = viser.ViserServer(host=host, port=int(port), label=self.title, verbose=not quiet)
        self.server = server
        server.gui.configure_theme(titlebar_content=None, control_width="medium", show_share_button=False)
        server.scene.set_up_direction("+z")
        server.scene.configure_fog(0.0, 1.0, enabled=False)  # the class colours as they are
        self._add_scene(server)
        if self._pending_field is None:  # else load_field adds them, with the field's cameras
            add_panels(self, server)
        self.url = f"http://{host}:{server.get_port()}"
        return self.url

    def _add_scene(self, server: Any) -> None:
        """The map's point clouds, the frusta and the initial camera."""
        m = self.map
        lo, hi = m.bounds
        occupied = m.label >= 0
        if occupied.any():
            ijk = np.argwhere(occupied)
            lo, hi = m.world_from_index(ijk.min(0)) - m.voxel_size, m.world_from_index(ijk.max(0)) + m.voxel_size
        centre, extent = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
        server.initial_camera.look_at = tuple(centre)
        server.initial_camera.position = tuple(centre + extent * np.array([0.55, -0.75, 0.6]))
        server.initial_camera.up = (0.0, 0.0, 1.0)
        for cid, centres in self._centres.items():
            color = UNKNOWN_COLOR if cid == UNKNOWN else self.palette[cid]
            name = "/map/unknown" if cid == UNKNOWN else f"/map/class_{cid}"
            shown = cid != UNKNOWN and len(centres) > 0  # UNKNOWN: a placeholder until ticked
            self.class_nodes[cid] = server.scene.add_point_cloud(
                name, centres if shown else np.zeros((1, 3), np.float32), color, point_size=m.voxel_size,
                point_shape="square", precision="float32", point_shading="gradient", visible=shown,
            )
            if shown:
                self._sent[cid] = len(centres)
        self._extent = extent
        self._add_frusta(server)

    def _add_frusta(self, server: Any) -> None:
        """The training cameras: every frustum in one line-segment node (one draw call, however many
        cameras) and each photo as an image on its frustum's rectangle."""
        if self.cameras is None:
            return
        segments = []
        for i in range(len(self.cameras)):
            cam = self.cameras[i]
            c2w = np.asarray(cam.c2w[0], np.float64)
            fov = 2 * math.atan(0.5 * float(cam.height[0]) / float(cam.fy[0]))
            seg, (half_w, half_h, depth) = frustum_segments(
                c2w, fov, float(cam.width[0]) / float(cam.height[0]), 0.035 * self._extent
            )
            segments.append(seg)
            image = self.view_images[i] if self.view_images else None
            if image is not None:
                self.frustum_nodes.append(server.scene.add_image(
                    f"/cameras/photo_{i}", image, 2 * half_w, 2 * half_h, format="jpeg",
                    wxyz=wxyz_from_rotation(c2w[:3, :3]), position=c2w[:3, :3] @ np.array([0.0, 0.0, depth]) + c2w[:3, 3],
                ))
        self.frustum_nodes.insert(0, server.scene.add_line_segments(
            "/cameras/frusta", np.concatenate(segments), (70, 70, 70), thickness=0.002 * self._extent,
        ))

    def wait_for_client(self, timeout: float = 30.0) -> Any:
        """Block until a browser is connected and has told its camera; returns its client handle.

        Raises:
            TimeoutError: none within ``timeout`` seconds.
        """
        deadline = time.monotonic() + timeout
        while True:
            for client in (self.server.get_clients() if self.server else {}).values():
                if client.camera.update_timestamp > 0:
                    return client
            if time.monotonic() >= deadline:
                break
            time.sleep(0.05)
        raise TimeoutError(f"no browser connected to {self.url} within {timeout:g} s")

    def serve_forever(self, timeout: float | None = None) -> None:
        """Block until Ctrl-C (or ``timeout`` seconds), then stop."""
        try:
            end = None if timeout is None else time.monotonic() + timeout
            while end is None or time.monotonic() < end:
                time.sleep(0.2 if end is None else max(0.0, min(0.2, end - time.monotonic())))
        finally:
            self.stop()

    def stop(self) -> None:
        """Stop serving (idempotent)."""
        if self.server is None:
            return
        server, self.server = self.server, None
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()
