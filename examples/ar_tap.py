"""AR tap: what does the ray through a tapped pixel hit, how far, and where?

Run on the toy scene (public API only: ``scenelabel.load_scene`` and ``SemanticField``)::

    scenelabel toy toy_scene && scenelabel build toy_scene --preset quick
    python examples/ar_tap.py toy_scene/scenelabel --view 1 --u 48 --v 36

or for a camera of your own (camera-to-world, OpenCV axes: x right, y down, z forward; 16 numbers,
row-major)::

    python examples/ar_tap.py toy_scene/scenelabel --c2w 1,0,0,0,0,-1,0,0,0,0,-1,2,0,0,0,1 \
        --focal 60 --cx 32 --cy 24 --u 32 --v 24

The ray goes through the **centre** of pixel (u, v): (u + 0.5, v + 0.5) in image coordinates
(docs/conventions.md), direction ``c2w[:3, :3] @ ((u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1)``
(distorted training cameras are undistorted with OpenCV first; a fisheye camera's ray follows its
lens model, docs/conventions.md "Camera models"). ``query_rays`` returns the class
hit, the depth (distance along the unit ray, world units) and the opacity; the hit point is
``origin + depth * direction``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from scenelabel import FREE, UNKNOWN, ScenelabelError, SemanticField, load_scene


def pixel_ray(c2w, fx, fy, cx, cy, u, v, distortion=None, model="pinhole"):
    """World origin [3] and unit direction [3] of the ray through the centre of pixel (u, v)."""
    uv = np.array([u + 0.5, v + 0.5])
    if model == "fisheye":  # OpenCV's equidistant fisheye: its rays may pass 90° off the axis
        from scenelabel.geometry.rays import camera_directions_from_pixels

        direction = c2w[:3, :3] @ camera_directions_from_pixels(uv[None], fx, fy, cx, cy, distortion, model)[0]
        return c2w[:3, 3].copy(), direction / np.linalg.norm(direction)
    if distortion is not None and np.any(distortion != 0):
        import cv2

        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], np.float64)
        xy = cv2.undistortPoints(uv.reshape(1, 1, 2), K, np.asarray(distortion, np.float64)).reshape(2)
    else:
        xy = (uv - (cx, cy)) / (fx, fy)
    direction = c2w[:3, :3] @ np.array([xy[0], xy[1], 1.0])
    return c2w[:3, 3].copy(), direction / np.linalg.norm(direction)


def camera(args):
    """(c2w [4, 4], fx, fy, cx, cy, width, height, distortion [4] or None, model) of the chosen camera."""
    if args.c2w:
        values = [float(x) for x in args.c2w.split(",")]
        if len(values) != 16:
            raise ValueError(f"--c2w needs 16 numbers, got {len(values)}")
        c2w = np.array(values).reshape(4, 4)
        if args.focal is None or args.cx is None or args.cy is None:
            raise ValueError("--c2w needs --focal, --cx and --cy")
        return c2w, args.focal, args.focal, args.cx, args.cy, None, None, None, "pinhole"
    scene_dir = Path(args.scene) if args.scene else Path(args.build).resolve().parent
    cams = load_scene(scene_dir).cameras  # scenelabel's Cameras: c2w in OpenCV axes
    if not 0 <= args.view < len(cams):
        raise ValueError(f"--view must be in [0, {len(cams) - 1}]")
    i = args.view
    return (cams.c2w[i], cams.fx[i], cams.fy[i], cams.cx[i], cams.cy[i], int(cams.width[i]), int(cams.height[i]),
            cams.distortion[i], str(cams.model[i]))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("build", help="build folder (scenelabel build's output)")
    parser.add_argument("--u", type=int, required=True, help="pixel column (0 = left)")
    parser.add_argument("--v", type=int, required=True, help="pixel row (0 = top)")
    parser.add_argument("--view", type=int, default=0, help="index of the scene's camera (default 0)")
    parser.add_argument("--scene", help="scene folder of the cameras (default: the build folder's parent)")
    parser.add_argument("--c2w", help="instead of a scene camera: 16 comma-separated numbers, OpenCV axes")
    parser.add_argument("--focal", type=float, help="focal length in pixels (with --c2w)")
    parser.add_argument("--cx", type=float, help="principal point x in pixels (with --c2w)")
    parser.add_argument("--cy", type=float, help="principal point y in pixels (with --c2w)")
    args = parser.parse_args(argv)

    try:
        field = SemanticField.load(args.build)
        c2w, fx, fy, cx, cy, width, height, distortion, model = camera(args)
        if width is not None and not (0 <= args.u < width and 0 <= args.v < height):
            raise ValueError(f"pixel ({args.u}, {args.v}) is outside the {width}x{height} image")
        origin, direction = pixel_ray(c2w, fx, fy, cx, cy, args.u, args.v, distortion, model)
        hit = field.query_rays(origin[None], direction[None])
    except (ScenelabelError, ValueError) as err:  # InputError is a ValueError too
        print(f"ar_tap: error: {err}", file=sys.stderr)
        return 2
    names = field.classes
    label, depth, opacity = int(hit.label[0]), float(hit.depth[0]), float(hit.opacity[0])
    print(f"ray through the centre of pixel ({args.u}, {args.v}): origin {np.round(origin, 4).tolist()}, "
          f"direction {np.round(direction, 4).tolist()}")
    if label == UNKNOWN:
        print("nothing: the ray never enters the modelled bounds (UNKNOWN)")
    elif label == FREE:
        print(f"nothing: the ray crosses the modelled bounds without a hit (FREE, opacity {opacity:.3f})")
    else:
        point = origin + depth * direction
        top = np.argsort(hit.probs[0])[::-1][:3]
        probs = ", ".join(f"{names[int(hit.class_ids[c])]} {hit.probs[0, c]:.2f}" for c in top)
        print(f"hit: {names[label]} (id {label}) at depth {depth:.4f}, point {np.round(point, 4).tolist()}, "
              f"opacity {opacity:.3f}; classes: {probs}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
