"""The analytic scenes with exact labels and depth: the toy two-box scene and a furnished room,
their camera paths, the writer of scene folders, and label noise.

The writers produce a scene folder in the ``transforms.json`` layout (see docs/conventions.md)::

    images/NNN.png      RGB 8-bit, 2x2 supersampled colour
    labels/NNN.png      single-channel 8-bit external class ids (ignore_index 255 = background)
    depths/NNN.npy      float32 [h, w] distance along the unit ray; 0 = no surface (background)
    classes.json        {"classes": [{"id", "name", "color"}...], "ignore_index": 255}
    transforms.json     nerfstudio convention: OpenGL camera-to-world ``transform_matrix``

Views form one closed, interleaved camera path, so that the project's default hold-out (every
8th view, ``index % 8 == 0``) picks views lying *between* training views (interpolations).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

from scenelabel.data.synthetic.geometry import BACKGROUND_ID, Box, ClassInfo, SyntheticScene
from scenelabel.data.synthetic.textures import checker_texture, plain_with_stripes, wall_texture, wood_texture
from scenelabel.data.synthetic.views import look_at, render_view
from scenelabel.errors import InputError
from scenelabel.geometry.boxes import box_corners

__all__ = [
    "HOLDOUT_EVERY",
    "NEAR_FACTOR",
    "FAR_FACTOR",
    "ROOM_HALF",
    "ROOM_HEIGHT",
    "ROOM_SLAB",
    "ROOM_BOXES",
    "ROOM_CLASSES",
    "TOY_BOXES",
    "TOY_CLASSES",
    "toy_scene_geometry",
    "furnished_room_geometry",
    "toy_cameras",
    "room_cameras",
    "write_scene",
    "write_toy_scene",
    "write_furnished_room",
    "corrupt_labels",
]

HOLDOUT_EVERY = 8  # the project's default hold-out: views with index % 8 == 0 are test views
NEAR_FACTOR, FAR_FACTOR = 0.8, 1.2  # per-frame near/far = factor * min/max true depth


# --------------------------------------------------------------------------------------------
# Scene definitions


def toy_scene_geometry() -> SyntheticScene:
    """The toy two-box scene (world z up, metres).

    Floor (id 1): slab [-1.5, 1.5]² x [-0.02, 0], top at z = 0. box_red (id 3):
    [-0.7, -0.2] x [-0.5, 0.0] x [0, 0.6]. box_blue (id 7): [0.1, 0.7] x [0.0, 0.5] x [0, 0.4].
    classes.json also lists chair (id 5), which no box carries. Background: white, label 255.
    """
    boxes = (
        Box((-1.5, -1.5, -0.02), (1.5, 1.5, 0.0), 1, "floor"),
        Box((-0.7, -0.5, 0.0), (-0.2, 0.0, 0.6), 3, "box_red"),
        Box((0.1, 0.0, 0.0), (0.7, 0.5, 0.4), 7, "box_blue"),
    )
    classes = (
        ClassInfo(1, "floor", (190, 170, 130)),
        ClassInfo(3, "box_red", (220, 40, 40)),
        ClassInfo(5, "chair", (40, 200, 60)),
        ClassInfo(7, "box_blue", (40, 80, 230)),
    )
    textures = {
        1: checker_texture((0.82, 0.76, 0.62), (0.56, 0.52, 0.44), period=0.5),
        3: plain_with_stripes((0.88, 0.22, 0.16)),
        7: plain_with_stripes((0.22, 0.38, 0.90)),
    }
    return SyntheticScene("toy_two_box", boxes, classes, textures, frame_id="toy_world")


ROOM_HALF = 3.0  # room interior [-3, 3]² x [0, ROOM_HEIGHT]
ROOM_HEIGHT = 2.6
ROOM_SLAB = 0.1  # thickness of walls, floor and ceiling slabs


def furnished_room_geometry() -> SyntheticScene:
    """A 6 x 6 x 2.6 m furnished room (interior [-3, 3]² x [0, 2.6]); cameras go inside.

    Classes (non-contiguous ids): floor 1, wall 2, ceiling 4, table 6, sofa 9, cabinet 12,
    lamp 20. The lamp pole is 5 cm thick (a thin obstacle).
    """
    h, s, top = ROOM_HALF, ROOM_SLAB, ROOM_HEIGHT
    boxes = [
        Box((-h - s, -h - s, -s), (h + s, h + s, 0.0), 1, "floor"),
        Box((-h - s, -h - s, top), (h + s, h + s, top + s), 4, "ceiling"),
        Box((-h - s, -h - s, 0.0), (-h, h + s, top), 2, "wall_x-"),
        Box((h, -h - s, 0.0), (h + s, h + s, top), 2, "wall_x+"),
        Box((-h, -h - s, 0.0), (h, -h, top), 2, "wall_y-"),
        Box((-h, h, 0.0), (h, h + s, top), 2, "wall_y+"),
        # table in the middle: top + four 5 cm legs
        Box((-0.6, -0.4, 0.72), (0.6, 0.4, 0.76), 6, "table_top"),
    ]
    for x0 in (-0.57, 0.52):
        for y0 in (-0.37, 0.32):
            boxes.append(Box((x0, y0, 0.0), (x0 + 0.05, y0 + 0.05, 0.72), 6, "table_leg"))
    boxes += [
        # sofa against the y+ wall
        Box((-1.2, 2.0, 0.0), (1.2, 2.95, 0.45), 9, "sofa_seat"),
        Box((-1.2, 2.7, 0.45), (1.2, 2.95, 0.9), 9, "sofa_back"),
        Box((-1.2, 2.0, 0.45), (-1.0, 2.7, 0.65), 9, "sofa_arm"),
        Box((1.0, 2.0, 0.45), (1.2, 2.7, 0.65), 9, "sofa_arm"),
        # cabinet against the x+ wall
        Box((2.5, -1.5, 0.0), (3.0, -0.3, 1.8), 12, "cabinet"),
        # floor lamp next to the sofa: base, 5 cm pole, shade
        Box((-1.9, 2.15, 0.0), (-1.55, 2.5, 0.04), 20, "lamp_base"),
        Box((-1.75, 2.3, 0.04), (-1.7, 2.35, 1.6), 20, "lamp_pole"),
        Box((-1.95, 2.1, 1.6), (-1.5, 2.55, 1.9), 20, "lamp_shade"),
    ]
    classes = (
        ClassInfo(1, "floor", (160, 110, 60)),
        ClassInfo(2, "wall", (200, 200, 170)),
        ClassInfo(4, "ceiling", (235, 235, 255)),
        ClassInfo(6, "table", (120, 60, 20)),
        ClassInfo(9, "sofa", (40, 170, 80)),
        ClassInfo(12, "cabinet", (50, 100, 220)),
        ClassInfo(20, "lamp", (240, 200, 20)),
    )
    textures = {
        1: wood_texture((0.80, 0.63, 0.42), (0.66, 0.50, 0.32), period=0.45, along_axis=1),
        2: wall_texture((0.88, 0.85, 0.78), (0.76, 0.78, 0.72), period=0.8),
        4: checker_texture((0.97, 0.97, 0.97), (0.86, 0.86, 0.90), period=1.0),
        6: wood_texture((0.45, 0.28, 0.16), (0.36, 0.21, 0.12), period=0.2, along_axis=0),
        9: checker_texture((0.25, 0.58, 0.36), (0.18, 0.45, 0.28), period=0.4),
        12: plain_with_stripes((0.30, 0.46, 0.74), amplitude=0.1, period=0.3),
        20: plain_with_stripes((0.95, 0.80, 0.30), amplitude=0.05, period=0.2),
    }
    return SyntheticScene("furnished_room", tuple(boxes), classes, textures, frame_id="room_world")


_TOY = toy_scene_geometry()
TOY_BOXES: tuple[Box, ...] = _TOY.boxes
TOY_CLASSES: tuple[ClassInfo, ...] = _TOY.classes
_ROOM = furnished_room_geometry()
ROOM_BOXES: tuple[Box, ...] = _ROOM.boxes
ROOM_CLASSES: tuple[ClassInfo, ...] = _ROOM.classes


# --------------------------------------------------------------------------------------------
# Camera paths (closed loops: view i sits between views i - 1 and i + 1)


def _check_split(n_train: int, n_test: int) -> int:
    """Total view count; n_test must be the number of views with index % HOLDOUT_EVERY == 0."""
    n_total = n_train + n_test
    if n_train < 1 or n_test < 0:
        raise InputError(f"need n_train >= 1 and n_test >= 0, got {n_train}, {n_test}", field="n_train")
    expected = len(range(0, n_total, HOLDOUT_EVERY))
    if n_test != expected:
        raise InputError(
            f"every {HOLDOUT_EVERY}th view is held out, so {n_total} views give {expected} test views, "
            f"not {n_test} (e.g. n_train={n_total - expected}, n_test={expected})",
            field="n_test",
        )
    return n_total


def toy_cameras(n_views: int, seed: int = 0) -> np.ndarray:
    """[n, 4, 4] OpenGL camera-to-world on a closed orbit around the toy scene.

    Radius 2.6-3.0 m, height 1.3-2.2 m, looking at a point near (0, 0, 0.2); evenly spaced
    azimuths (jittered by up to a quarter step with ``seed``), so every view is between its
    neighbours.
    """
    rng = np.random.default_rng(seed)
    i = np.arange(n_views)
    phase = 2 * np.pi * i / n_views
    azimuth = phase + rng.uniform(0, 2 * np.pi) + rng.uniform(-0.25, 0.25, n_views) * 2 * np.pi / n_views
    radius = 2.8 + 0.2 * np.sin(3 * phase + rng.uniform(0, 2 * np.pi))
    height = 1.75 + 0.45 * np.sin(2 * phase + rng.uniform(0, 2 * np.pi))
    targets = np.array([0.0, 0.0, 0.2]) + rng.uniform(-0.05, 0.05, (n_views, 3))
    eyes = np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), height], axis=-1)
    return np.stack([look_at(e, t) for e, t in zip(eyes, targets)])


def room_cameras(n_views: int, seed: int = 0, scene: SyntheticScene | None = None) -> np.ndarray:
    """[n, 4, 4] OpenGL camera-to-world on a closed loop inside the furnished room.

    Cameras circle the table at 1.5-2.0 m from the room centre, heights 1.0-1.8 m, and look
    across the room at targets that swing between walls and furniture, tilting up and down
    from one view to the next (target heights 0.1-2.3 m) like a person scanning a room, so the
    ceiling and the floor behind furniture are seen by training views too: at least 99% of the
    held-out views' labelled pixels are seen by a training view (every 8th view held out,
    seeds 0 and 1; tests/test_synthetic.py checks the ceiling).
    """
    scene = _ROOM if scene is None else scene
    rng = np.random.default_rng(seed)
    i = np.arange(n_views)
    phase = 2 * np.pi * i / n_views
    azimuth = phase + rng.uniform(0, 2 * np.pi) + rng.uniform(-0.2, 0.2, n_views) * 2 * np.pi / n_views
    radius = 1.75 + 0.25 * np.sin(3 * phase + rng.uniform(0, 2 * np.pi))
    height = 1.4 + 0.4 * np.sin(2 * phase + rng.uniform(0, 2 * np.pi))
    eyes = np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), height], axis=-1)
    swing = 0.8 * np.sin(5 * phase)  # look direction swings +-0.8 rad around "across the room"
    look_az = azimuth + np.pi + swing
    target_dist = 2.0
    targets = np.stack(
        [
            eyes[:, 0] + target_dist * np.cos(look_az),
            eyes[:, 1] + target_dist * np.sin(look_az),
            1.2 + 1.1 * np.sin(17 * phase + 1.0),  # 17 cycles per loop: neighbours alternate up / down
        ],
        axis=-1,
    )
    margin = 0.2
    for eye in eyes:
        for box in scene.boxes:
            if np.all(eye > np.asarray(box.lo) - margin) and np.all(eye < np.asarray(box.hi) + margin):
                raise AssertionError(f"room camera at {eye} is within {margin} m of {box.part}")
    return np.stack([look_at(e, t) for e, t in zip(eyes, targets)])


# --------------------------------------------------------------------------------------------
# Writers


def _focal_from_fov(width: int, fov_x_deg: float) -> float:
    return (width / 2.0) / math.tan(math.radians(fov_x_deg) / 2.0)


def write_scene(
    path: str | Path, scene: SyntheticScene, c2ws: np.ndarray, width: int, height: int,
    fov_x_deg: float = 50.0, bounds_in_file: bool = True,
) -> Path:
    """Render every camera of ``c2ws`` ([n, 4, 4] OpenGL) and write the scene folder.

    With ``bounds_in_file`` (default), every frame gets ``near``/``far`` and the file a top-level
    ``aabb`` (:attr:`SyntheticScene.aabb`): per-frame near/far are NEAR_FACTOR x min and
    FAR_FACTOR x max of the true depth over the frame's hit pixels (background ignored); a frame
    that sees nothing gets the range of the scene's aabb corners. With ``bounds_in_file=False``
    neither per-frame near/far nor ``aabb`` is written, like users' files (nerfstudio never
    writes them); everything else is identical. Returns the folder path.
    """
    if width < 1 or height < 1:
        raise InputError(f"image size must be positive, got {width}x{height}", field="width")
    root = Path(path)
    for sub in ("images", "labels", "depths"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    f = _focal_from_fov(width, fov_x_deg)
    cx, cy = width / 2.0, height / 2.0
    aabb = scene.aabb
    corners = box_corners(aabb)
    frames = []
    digits = max(3, len(str(len(c2ws) - 1)))
    for index, c2w in enumerate(c2ws):
        rgb, labels, depth = render_view(scene, c2w, f, f, cx, cy, width, height)
        name = f"{index:0{digits}d}"
        Image.fromarray(np.round(rgb * 255.0).astype(np.uint8)).save(root / "images" / f"{name}.png")
        Image.fromarray(labels.astype(np.uint8)).save(root / "labels" / f"{name}.png")
        np.save(root / "depths" / f"{name}.npy", depth.astype(np.float32))
        hit_depth = depth[depth > 0]
        if hit_depth.size:
            near, far = NEAR_FACTOR * hit_depth.min(), FAR_FACTOR * hit_depth.max()
        else:
            dist = np.linalg.norm(corners - c2w[:3, 3], axis=1)
            near, far = max(1e-3, NEAR_FACTOR * dist.min()), FAR_FACTOR * dist.max()
        frame = {
            "file_path": f"images/{name}.png",
            "label_path": f"labels/{name}.png",
            "depth_path": f"depths/{name}.npy",
            "transform_matrix": np.asarray(c2w, np.float64).tolist(),
        }
        if bounds_in_file:
            frame["near"], frame["far"] = float(near), float(far)
        frames.append(frame)
    transforms = {
        "camera_model": "PINHOLE",
        "fl_x": f,
        "fl_y": f,
        "cx": cx,
        "cy": cy,
        "w": int(width),
        "h": int(height),
        "frame_id": scene.frame_id,
        "aabb": aabb.tolist(),
        "frames": frames,
    }
    if not bounds_in_file:
        del transforms["aabb"]
    classes = {
        "classes": [{"id": c.id, "name": c.name, "color": list(c.color)} for c in scene.classes],
        "ignore_index": scene.ignore_index,
    }
    (root / "transforms.json").write_text(json.dumps(transforms, indent=2))
    (root / "classes.json").write_text(json.dumps(classes, indent=2))
    return root


def write_toy_scene(
    path: str | Path, n_train: int = 28, n_test: int = 4, width: int = 96, height: int = 72, seed: int = 0
) -> Path:
    """Write the toy two-box scene (:func:`toy_scene_geometry`) to ``path``.

    ``n_train + n_test`` views on one interleaved orbit; views with index % 8 == 0 are the
    held-out ones, so ``n_test`` must equal their count (4 for 32 views). Horizontal FOV 50°.
    Deterministic for a seed. Returns the folder path.
    """
    n_total = _check_split(n_train, n_test)
    return write_scene(path, _TOY, toy_cameras(n_total, seed), width, height)


def write_furnished_room(
    path: str | Path, n_train: int = 35, n_test: int = 5, width: int = 160, height: int = 120, seed: int = 0
) -> Path:
    """Write the furnished room (:func:`furnished_room_geometry`) to ``path``.

    40 views by default (every 8th held out: 5 test views), cameras inside the room, so every
    ray hits a surface. Horizontal FOV 50°. Deterministic for a seed. Returns the folder path.
    """
    n_total = _check_split(n_train, n_test)
    return write_scene(path, _ROOM, room_cameras(n_total, seed), width, height)


# --------------------------------------------------------------------------------------------
# Label noise (what a real 2D segmenter's mistakes look like: blobs of a wrong class)


def corrupt_labels(
    label: np.ndarray, fraction: float, class_ids, rng: np.random.Generator, ignore_index: int | None = BACKGROUND_ID
) -> np.ndarray:
    """A copy of ``label`` with random discs of wrong classes over ~``fraction`` of its labelled pixels.

    Discs (radius 3-12% of the image's shorter side) are painted one by one, each with a class
    drawn from ``class_ids``; a pixel counts as corrupted once its class differs from the
    original. Painting stops as soon as at least ``fraction`` of the labelled (not
    ``ignore_index``) pixels are corrupted, so the result is within one disc of the target.

    Args:
        label: [H, W] int class ids.
        fraction: in [0, 1).
        class_ids: the classes the blobs may take (at least two).
        rng: numpy Generator (deterministic for a seed).
    Returns:
        [H, W] int64.
    """
    if not 0.0 <= fraction < 1.0:
        raise InputError(f"fraction must be in [0, 1), got {fraction}", field="fraction")
    class_ids = np.asarray(sorted(set(int(c) for c in class_ids)), dtype=np.int64)
    if len(class_ids) < 2:
        raise InputError("corrupting labels needs at least two classes", field="class_ids")
    original = np.asarray(label, dtype=np.int64)
    out = original.copy()
    labelled = original != ignore_index if ignore_index is not None else np.ones(original.shape, bool)
    n_labelled = int(labelled.sum())
    h, w = original.shape
    rows, cols = np.mgrid[0:h, 0:w]
    short = min(h, w)
    while n_labelled and ((out != original) & labelled).sum() < fraction * n_labelled:
        r = rng.uniform(0.03, 0.12) * short
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        disc = ((rows - cy) ** 2 + (cols - cx) ** 2 <= r * r) & labelled
        out[disc] = rng.choice(class_ids)
    return out
