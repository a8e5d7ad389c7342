"""A synthetic room filmed hand-held: a video file, labels per frame and the true poses.

:func:`write_room_video` renders a room of the scene suite (:mod:`scenelabel.data.suite`), its
textures given fine detail (:func:`with_detail`), with the exact ray caster, one ray per pixel
centre (colour and labels from the same ray), along a smooth walk (:func:`video_camera_path`):
round the free floor space along the walls at a walking speed, looking across the room with a
slow swing left / right, a gentle tilt up / down and a small hand-held shake (position, direction
and roll). A fraction of the frames gets a linear motion blur (:func:`motion_blur`), so that frame
choice has blurred frames to drop. Written (``clip.mp4``):

- ``clip.mp4``: the video (OpenCV ``VideoWriter``, MPEG-4 part 2 ``mp4v``; any suffix OpenCV can
  write with that codec);
- ``clip/labels/frame_NNNNNN.png`` for every frame (NNNNNN the 0-based frame index, the names
  :func:`scenelabel.data.video.frames_from_video` gives frames) and ``clip/classes.json``: the
  scene folder a build of ``clip.mp4`` uses, so its held-out views are scored;
- ``clip_poses.json`` beside the video: the truth, not an input: intrinsics and per frame its
  camera-to-world (OpenCV axes, the room's frame, metres) and whether it was blurred.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from scenelabel.data.suite import check_cameras, loop_positions
from scenelabel.data.synthetic.geometry import SyntheticScene, cast_rays, shade_hits
from scenelabel.data.synthetic.views import look_at, pixel_rays
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import opengl_to_opencv

__all__ = [
    "RoomVideo",
    "VIDEO_ROOM",
    "video_camera_path",
    "with_detail",
    "motion_blur",
    "write_room_video",
    "read_video_truth",
]

#: The suite room filmed by default (mixed textures: enough detail for SIFT).
VIDEO_ROOM = "living-6x5"
WALK_SPEED = 0.35  # m/s along the camera loop
EYE_HEIGHT = 1.45  # m, +- EYE_SWAY
EYE_SWAY = 0.12
SWING = 0.3  # rad: the view swings this far left / right of "towards the room's centre"
SWING_PERIOD = 14.0  # s
TILT_PERIOD = 10.0  # s: the target height goes between TARGET_LOW and TARGET_HIGH and back in this time
TARGET_LOW, TARGET_HIGH = 0.6, 1.8  # m, heights of the look-at point
TARGET_DISTANCE = 2.5  # m ahead
SHAKE_POSITION = 0.01  # m: hand-held shake of the camera centre (amplitude)
SHAKE_ANGLE = math.radians(0.6)  # rad: hand-held shake of the direction and roll (amplitude)
BLUR_LENGTH = 0.025  # a blurred frame's motion streak, as a fraction of the image width (at least 5 px)
DETAIL_CELL = 0.015  # m: texel of the fine surface detail (:func:`with_detail`)
DETAIL_TEXELS = 512  # detail grid side (texels; it repeats every DETAIL_TEXELS * DETAIL_CELL m)


@dataclass(frozen=True)
class RoomVideo:
    """What :func:`write_room_video` wrote.

    Attributes:
        video: the video file.
        scene_dir: its scene folder (``labels/``, ``classes.json``).
        truth_path: the ``<stem>_poses.json`` truth file.
        c2w: [n, 4, 4] camera-to-world per frame, OpenCV axes (the room's frame, metres).
        blurred: indices of the frames given motion blur.
        fps, width, height, fx, fy, cx, cy: frame rate and pinhole intrinsics (pixels).
    """

    video: Path
    scene_dir: Path
    truth_path: Path
    c2w: np.ndarray
    blurred: tuple[int, ...]
    fps: float
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


def _shake(t: np.ndarray, rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """[n, 3] smooth hand-held shake at times t [n] (s): sums of sines of 0.3-1.5 Hz, peak ~ amplitude."""
    freqs = rng.uniform(0.3, 1.5, (3, 4))
    phases = rng.uniform(0, 2 * np.pi, (3, 4))
    waves = np.sin(2 * np.pi * freqs[None] * t[:, None, None] + phases[None])  # [n, 3, 4]
    return amplitude * waves.sum(-1) / 2.0


def video_camera_path(scene: SyntheticScene, spec, times: np.ndarray, seed: int = 0) -> np.ndarray:
    """[n, 4, 4] OpenGL camera-to-world of a smooth hand-held walk at times ``times`` [n] (s).

    The walk follows the suite's "walk" loop of ``spec`` (:class:`scenelabel.data.suite.SuiteSpec`:
    the boundary of the free floor space 0.6 m from walls and furniture) at WALK_SPEED from a
    seeded start, eye height EYE_HEIGHT +- EYE_SWAY. The camera looks towards the loop's centre
    +- SWING (period SWING_PERIOD) at a point TARGET_DISTANCE ahead whose height goes between
    TARGET_LOW and TARGET_HIGH (period TILT_PERIOD), plus a smooth shake of SHAKE_POSITION (centre)
    and SHAKE_ANGLE (direction and roll).
    """
    spec = dataclasses.replace(spec, path="walk")
    rng = np.random.default_rng([seed, 7])
    loop, pole = loop_positions(spec, scene)
    closed = np.concatenate([loop, loop[:1]])
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    s = (rng.uniform(0, cum[-1]) + WALK_SPEED * np.asarray(times, np.float64)) % cum[-1]
    xy = np.stack([np.interp(s, cum, closed[:, 0]), np.interp(s, cum, closed[:, 1])], -1)
    phase = rng.uniform(0, 2 * np.pi, 3)
    z = EYE_HEIGHT + EYE_SWAY * np.sin(2 * np.pi * times / (1.7 * TILT_PERIOD) + phase[0])
    eyes = np.concatenate([xy, z[:, None]], axis=1) + _shake(times, rng, SHAKE_POSITION)
    az = np.arctan2(pole[1] - xy[:, 1], pole[0] - xy[:, 0])
    az = np.unwrap(az) + SWING * np.sin(2 * np.pi * times / SWING_PERIOD + phase[1])
    mid, half = (TARGET_LOW + TARGET_HIGH) / 2, (TARGET_HIGH - TARGET_LOW) / 2
    tz = mid + half * np.sin(2 * np.pi * times / TILT_PERIOD + phase[2])
    targets = np.stack([xy[:, 0] + TARGET_DISTANCE * np.cos(az), xy[:, 1] + TARGET_DISTANCE * np.sin(az), tz], 1)
    angles = _shake(times, rng, SHAKE_ANGLE)  # [n, 3]: yaw, pitch, roll shake
    c2ws = []
    for eye, target, (yaw, pitch, roll) in zip(eyes, targets, angles):
        c2w = look_at(eye, target)
        shake = cv2.Rodrigues(np.array([pitch, yaw, roll]))[0]  # about the camera's x, y, z (OpenGL)
        c2w[:3, :3] = c2w[:3, :3] @ shake
        c2ws.append(c2w)
    check_cameras(spec, scene, eyes)
    return np.stack(c2ws)


def with_detail(scene: SyntheticScene, amount: float, seed: int = 0) -> SyntheticScene:
    """``scene`` with fine surface detail on every texture, as real rooms have (dust, grain, print).

    Each class's colour is multiplied by ``1 + amount * (n - 0.5) * 2`` where ``n`` in [0, 1] is a
    seeded multi-scale noise (Gaussian-smoothed random grids of 1, 4 and 12 texels of DETAIL_CELL,
    one per colour channel, wrapping) over the face's two in-plane coordinates, offset per face axis
    so that faces of different orientation differ. Structure from motion needs such corners and
    blobs: the suite's smooth stripes alone give SIFT too few. ``amount`` 0 leaves the scene as it is.
    """
    from scipy import ndimage

    if amount <= 0:
        return scene
    rng = np.random.default_rng([seed, 9])
    textures = dict(scene.textures)
    for class_id in scene.present_ids:
        texture = scene.textures[class_id]
        grid = np.zeros((3, DETAIL_TEXELS, DETAIL_TEXELS))
        for sigma, weight in ((1.0, 1.0), (4.0, 1.5), (12.0, 2.0)):
            noise = rng.random((3, DETAIL_TEXELS, DETAIL_TEXELS))
            grid += weight * ndimage.gaussian_filter(noise, (0, sigma, sigma), mode="wrap")
        grid -= grid.min(axis=(1, 2), keepdims=True)
        grid /= grid.max(axis=(1, 2), keepdims=True)
        textures[class_id] = _detailed(texture, grid, amount)
    return dataclasses.replace(scene, textures=textures)


def _detailed(texture, grid: np.ndarray, amount: float):
    """``texture`` times ``1 + amount * (2 grid(face coordinates) - 1)`` (see :func:`with_detail`)."""
    from scipy import ndimage

    def detailed(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        axis = np.abs(normals).argmax(axis=1)
        a = np.where(axis == 0, points[:, 1], points[:, 0]) / DETAIL_CELL + 97.0 * axis
        b = np.where(axis == 2, points[:, 1], points[:, 2]) / DETAIL_CELL + 31.0 * axis
        n = np.stack([ndimage.map_coordinates(g, [a, b], order=1, mode="grid-wrap") for g in grid], axis=1)
        return np.clip(texture(points, normals) * (1.0 + amount * (2.0 * n - 1.0)), 0.0, 1.0)

    return detailed


def motion_blur(image: np.ndarray, length: int, angle_deg: float) -> np.ndarray:
    """A linear motion blur: the mean of ``image`` along a ``length``-pixel streak at ``angle_deg``.

    Args:
        image: [h, w, 3] uint8 or float.
        length: streak length in pixels (>= 1; 1 leaves the image as it is).
        angle_deg: streak direction, degrees from the image x axis.
    Returns:
        the blurred image, same shape and dtype (borders reflected).
    """
    length = max(1, int(length))
    kernel = np.zeros((length, length), np.float32)
    c = (length - 1) / 2.0
    dx, dy = math.cos(math.radians(angle_deg)) * c, math.sin(math.radians(angle_deg)) * c
    cv2.line(kernel, (round(c - dx), round(c - dy)), (round(c + dx), round(c + dy)), 1.0, 1)
    kernel /= kernel.sum()
    return cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REFLECT)


def write_room_video(
    path: str | Path,
    seconds: float = 30.0,
    fps: float = 10.0,
    width: int = 640,
    height: int = 480,
    room: str = VIDEO_ROOM,
    blur_fraction: float = 0.15,
    detail: float = 0.35,
    seed: int = 0,
    progress: bool = False,
) -> RoomVideo:
    """Film a suite room along :func:`video_camera_path` into the video ``path`` (see the module docstring).

    Args:
        path: the video file to write (``.mp4``); its scene folder ``<stem>/`` gets labels/ and
            classes.json, and ``<stem>_poses.json`` the truth.
        seconds, fps: clip length and frame rate (``round(seconds * fps)`` frames).
        width, height: frame size in pixels; horizontal field of view 60° (the suite's).
        room: a :data:`scenelabel.data.suite.SUITE` room name.
        blur_fraction: this fraction of the frames (seeded, never the first or last) gets a
            motion blur of BLUR_LENGTH x width pixels at a random angle.
        detail: fine surface detail added to the room's textures (:func:`with_detail`; 0: none).
        seed: path, shake and blur seed (deterministic).
        progress: a progress bar.
    Returns:
        the :class:`RoomVideo`.
    """
    from tqdm import tqdm

    from scenelabel.data.suite import FOV_X_DEG, suite_geometry, suite_spec
    from scenelabel.data.video import frame_name, video_scene_dir

    n = round(seconds * fps)
    if n < 2 or width < 8 or height < 8:
        raise InputError(f"need at least 2 frames of at least 8x8 pixels, got {n} of {width}x{height}", field="seconds")
    path = Path(path)
    spec = suite_spec(room)
    scene = with_detail(suite_geometry(spec), detail, seed)
    times = np.arange(n) / fps
    c2ws = video_camera_path(scene, spec, times, seed)
    f = (width / 2.0) / math.tan(math.radians(FOV_X_DEG) / 2.0)
    cx, cy = width / 2.0, height / 2.0
    rng = np.random.default_rng([seed, 8])
    n_blur = round(blur_fraction * n)
    blurred = np.sort(rng.choice(np.arange(1, n - 1), size=min(n_blur, max(0, n - 2)), replace=False)) if n > 2 else []
    blurred = tuple(int(i) for i in blurred)
    streak = max(5, round(BLUR_LENGTH * width))

    scene_dir = video_scene_dir(path)
    (scene_dir / "labels").mkdir(parents=True, exist_ok=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (width, height))
    if not writer.isOpened():
        raise InputError("OpenCV cannot write this video (mp4v codec): use a .mp4 name", path)
    try:
        for index in tqdm(range(n), disable=not progress, unit="frame", desc="rendering", dynamic_ncols=True):
            origins, directions = pixel_rays(c2ws[index], f, f, cx, cy, width, height)
            hits = cast_rays(origins.reshape(-1, 3), directions.reshape(-1, 3), scene.boxes, scene.ignore_index)
            rgb = np.round(shade_hits(hits, scene).reshape(height, width, 3) * 255.0).astype(np.uint8)
            if index in blurred:
                rgb = motion_blur(rgb, streak, rng.uniform(0, 180))
            writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            label = hits.class_id.reshape(height, width).astype(np.uint8)
            Image.fromarray(label).save(scene_dir / "labels" / frame_name(index).replace(".jpg", ".png"))
    finally:
        writer.release()
    classes = {
        "classes": [{"id": c.id, "name": c.name, "color": list(c.color)} for c in scene.classes],
        "ignore_index": scene.ignore_index,
    }
    (scene_dir / "classes.json").write_text(json.dumps(classes, indent=2))
    c2w_cv = np.stack([opengl_to_opencv(c) for c in c2ws])
    truth = {
        "about": "true cameras of the video's frames: c2w camera-to-world, OpenCV axes, room frame, metres",
        "room": room,
        "fps": float(fps),
        "width": int(width),
        "height": int(height),
        "fx": f, "fy": f, "cx": cx, "cy": cy,
        "frames": [
            {"index": i, "name": frame_name(i), "c2w": c2w_cv[i].tolist(), "blurred": i in blurred} for i in range(n)
        ],
    }
    truth_path = path.with_name(f"{path.stem}_poses.json")
    truth_path.write_text(json.dumps(truth))
    return RoomVideo(path, scene_dir, truth_path, c2w_cv, blurred, float(fps), width, height, f, f, cx, cy)


def read_video_truth(truth_path: str | Path) -> tuple[dict[int, np.ndarray], set[int]]:
    """The true poses of a :func:`write_room_video` truth file.

    Returns:
        ({frame index: [4, 4] c2w, OpenCV axes}, the set of blurred frame indices).
    """
    data = json.loads(Path(truth_path).read_text())
    poses = {int(f["index"]): np.asarray(f["c2w"], np.float64) for f in data["frames"]}
    return poses, {int(f["index"]) for f in data["frames"] if f["blurred"]}
