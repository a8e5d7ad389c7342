"""nerfstudio's ``applied_transform``: the rigid transform ``ns-process-data`` applied to the
original world frame (e.g. COLMAP's) to produce the ``transform_matrix`` poses.

nerfstudio's dataparser documents it as "the transformation to saved coordinates from original
data coordinates": ``transform_matrix = A @ T_original`` with ``A`` the 3x4 (made 4x4). The COLMAP
converter writes ``A = [[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]]`` (world y and z swapped, z
negated: COLMAP's y-down world becomes z-up) unless run with ``--keep-original-world-coordinate``;
datasets converted before the key existed and holding ``colmap/sparse/0`` had
``[[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 0]]`` applied (nerfstudio assumes so; so does
:func:`applied_transform_of`). Polycam and Record3D conversions apply none.

scenelabel keeps the ``transform_matrix`` frame as its world frame by default (maps and exports
line up with what nerfstudio's tools show) and records ``A`` in ``Scene.info``;
``load_transforms(..., world_frame="original")`` loads in the original frame instead:
``c2w_original = A^-1 @ c2w`` (a left-multiplication, so it commutes with the OpenGL -> OpenCV
camera-axis flip on the right).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from scenelabel.data.io.common import check_pose
from scenelabel.errors import InputError
from scenelabel.geometry.boxes import box_corners

__all__ = [
    "WORLD_FRAMES",
    "LEGACY_COLMAP_APPLIED_TRANSFORM",
    "check_applied_transform",
    "applied_transform_of",
    "original_frame_c2w",
    "original_frame_aabb",
]

#: ``load_transforms(world_frame=...)``: "transforms" keeps the transform_matrix frame (default),
#: "original" undoes applied_transform.
WORLD_FRAMES = ("transforms", "original")

#: What nerfstudio assumes was applied to a COLMAP dataset written before ``applied_transform``
#: was recorded (a ``colmap/sparse/0`` folder and no key).
LEGACY_COLMAP_APPLIED_TRANSFORM = ((0.0, 1.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, -1.0, 0.0))

#: The legacy rule applies when the scene folder holds this.
_LEGACY_COLMAP_FOLDER = Path("colmap") / "sparse" / "0"


def check_applied_transform(value: Any, path: Path | None = None, field: str = "$.applied_transform") -> np.ndarray:
    """An ``applied_transform`` as float64 [4, 4], checked.

    Accepts [3, 4] (bottom row [0, 0, 0, 1] added) or [4, 4]; entries finite; the rotation rigid
    and right-handed (``max|R^T R - I| <= ROTATION_TOLERANCE``, ``det R > 0``: no scale, no mirror).

    Raises:
        InputError: one line naming the problem, the file and the key.
    """
    try:
        matrix = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("applied_transform must be a 3x4 or 4x4 matrix of numbers", path, field=field) from None
    return check_pose(matrix, path, field, what="applied_transform")


def applied_transform_of(data: dict, root: Path, path: Path) -> tuple[np.ndarray | None, str | None]:
    """The transform a transforms.json's poses went through, and where it comes from.

    Returns:
        ([4, 4] float64, "file") when the file has ``applied_transform``; (the legacy COLMAP
        transform, "nerfstudio legacy COLMAP default") when it has none but ``root`` holds
        ``colmap/sparse/0``; (None, None) otherwise (the original frame is the file's).
    """
    if "applied_transform" in data:
        return check_applied_transform(data["applied_transform"], path), "file"
    if (Path(root) / _LEGACY_COLMAP_FOLDER).is_dir():
        return check_applied_transform(LEGACY_COLMAP_APPLIED_TRANSFORM, path), "nerfstudio legacy COLMAP default"
    return None, None


def original_frame_c2w(c2w: np.ndarray, applied: np.ndarray) -> np.ndarray:
    """Poses in the original world frame: ``A^-1 @ c2w``.

    Args:
        c2w: [n, 4, 4] camera-to-world in the transform_matrix frame (any camera axes).
        applied: [4, 4] rigid ``A``.
    Returns:
        [n, 4, 4] float64.
    """
    return np.linalg.inv(np.asarray(applied, np.float64)) @ np.asarray(c2w, np.float64)


def original_frame_aabb(aabb: np.ndarray, applied: np.ndarray) -> np.ndarray:
    """The axis-aligned box [2, 3] containing ``aabb`` (transform_matrix frame) in the original frame.

    A rotation other than an axis permutation makes the box larger than the volume it bounds.
    """
    corners = np.concatenate([box_corners(aabb), np.ones((8, 1))], axis=1)  # homogeneous
    moved = corners @ np.linalg.inv(np.asarray(applied, np.float64)).T
    return np.stack([moved[:, :3].min(axis=0), moved[:, :3].max(axis=0)])
