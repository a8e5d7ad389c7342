"""Scene data: cameras, images, label maps and the class map, in scenelabel's conventions.

Every loader in :mod:`scenelabel.io` converts its input into these types; see docs/conventions.md.

- Cameras: ``c2w`` is camera-to-world with **OpenCV camera axes** (x right, y down, z forward),
  in the input's own world frame and units. Intrinsics in pixels; the centre of pixel (col, row)
  is at (col + 0.5, row + 0.5).
- Images: float32 RGB in [0, 1], shape [height, width, 3].
- Labels: int64 external class ids (those of classes.json), shape [height, width];
  ``ignore_index`` marks unlabelled pixels.
- Depths (ground truth, synthetic scenes only): distance along the unit ray direction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = ["Cameras", "Scene", "ClassMap", "UNLABELLED_NAME"]

#: Class name of the single channel of a build without labels (photometric only).
UNLABELLED_NAME = "unlabelled"


@dataclass(frozen=True)
class Cameras:
    """A batch of pinhole cameras (optionally with OpenCV radial-tangential distortion).

    Attributes:
        c2w: [n, 4, 4] float64 camera-to-world, OpenCV axes (x right, y down, z forward).
        fx, fy, cx, cy: [n] float64 intrinsics in pixels (cx, cy from the top-left image corner).
        width, height: [n] int64 image size in pixels.
        distortion: [n, 4] float64 OpenCV (k1, k2, p1, p2); zeros for an ideal pinhole.
        near, far: [n] float64 scene depth range seen by each camera (distance along the unit
            ray); NaN where the input does not say.
    """

    c2w: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    width: np.ndarray
    height: np.ndarray
    distortion: np.ndarray
    near: np.ndarray
    far: np.ndarray

    def __post_init__(self) -> None:
        n = self.c2w.shape[0] if self.c2w.ndim == 3 else -1
        if self.c2w.shape != (n, 4, 4):
            raise InputError(f"c2w must have shape [n, 4, 4], got {self.c2w.shape}", field="c2w")
        for name in ("fx", "fy", "cx", "cy", "width", "height", "near", "far"):
            if getattr(self, name).shape != (n,):
                raise InputError(f"{name} must have shape [{n}], got {getattr(self, name).shape}", field=name)
        if self.distortion.shape != (n, 4):
            raise InputError(f"distortion must have shape [{n}, 4], got {self.distortion.shape}", field="distortion")

    @staticmethod
    def create(
        c2w: np.ndarray,
        fx,
        fy,
        cx,
        cy,
        width,
        height,
        distortion=None,
        near=None,
        far=None,
    ) -> "Cameras":
        """Build cameras from per-camera arrays or scalars broadcast to all cameras."""
        c2w = np.asarray(c2w, dtype=np.float64)
        if c2w.ndim == 2:
            c2w = c2w[None]
        n = c2w.shape[0]

        def per_cam(value, dtype, default=np.nan):
            value = default if value is None else value
            return np.broadcast_to(np.asarray(value, dtype=dtype), (n,)).copy()

        dist = np.zeros((n, 4)) if distortion is None else np.broadcast_to(np.asarray(distortion, np.float64), (n, 4)).copy()
        return Cameras(
            c2w=c2w,
            fx=per_cam(fx, np.float64),
            fy=per_cam(fy, np.float64),
            cx=per_cam(cx, np.float64),
            cy=per_cam(cy, np.float64),
            width=per_cam(width, np.int64),
            height=per_cam(height, np.int64),
            distortion=dist,
            near=per_cam(near, np.float64),
            far=per_cam(far, np.float64),
        )

    def __len__(self) -> int:
        return self.c2w.shape[0]

    def __getitem__(self, index) -> "Cameras":
        """Cameras at ``index`` (an int, slice, or index array); always a batch."""
        index = np.atleast_1d(np.arange(len(self))[index])
        return Cameras(**{name: getattr(self, name)[index] for name in self.__dataclass_fields__})

    @property
    def centres(self) -> np.ndarray:
        """[n, 3] camera centres in world coordinates."""
        return self.c2w[:, :3, 3]

    @property
    def has_distortion(self) -> np.ndarray:
        """[n] bool: the camera has non-zero distortion coefficients."""
        return np.any(self.distortion != 0, axis=1)


@dataclass
class Scene:
    """A loaded scene: cameras plus per-view images, optional labels and optional depths.

    Attributes:
        root: the scene folder.
        cameras: one camera per view.
        names: [n] view names (image file stems).
        images: n arrays [h, w, 3] float32 in [0, 1].
        labels: n arrays [h, w] int64 of external class ids, or None for an unlabelled view.
        depths: n arrays [h, w] float32 ground-truth depth along the unit ray, or None.
        classes: the full vocabulary of classes.json: external id -> name.
        ignore_index: the label value of unlabelled pixels, or None.
        aabb: [2, 3] explicit scene bounds (min corner, max corner) from the input, or None.
        frame_id: name of the world frame (for exports).
    """

    root: Path
    cameras: Cameras
    names: list[str]
    images: list[np.ndarray]
    labels: list[np.ndarray | None]
    depths: list[np.ndarray | None]
    classes: dict[int, str]
    ignore_index: int | None = None
    aabb: np.ndarray | None = None
    frame_id: str = "world"
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.cameras)

    def scaled(self, factor: float) -> "Scene":
        """This scene with world lengths multiplied by ``factor`` (camera centres, near/far, depths, aabb).

        For inputs of arbitrary scale (COLMAP, SfM): ``factor`` = metres per input unit makes every
        output metric. Rotations, intrinsics and images are unchanged. ``info["world_scale"]`` records
        the factor (products of repeated calls).
        """
        factor = float(factor)
        if not (np.isfinite(factor) and factor > 0):
            raise InputError(f"scale must be a positive finite number, got {factor}", field="scale")
        c2w = self.cameras.c2w.copy()
        c2w[:, :3, 3] *= factor
        cameras = Cameras(**{**vars(self.cameras), "c2w": c2w, "near": self.cameras.near * factor, "far": self.cameras.far * factor})
        return Scene(
            root=self.root,
            cameras=cameras,
            names=list(self.names),
            images=self.images,
            labels=self.labels,
            depths=[None if d is None else d * np.float32(factor) for d in self.depths],
            classes=dict(self.classes),
            ignore_index=self.ignore_index,
            aabb=None if self.aabb is None else np.asarray(self.aabb, np.float64) * factor,
            frame_id=self.frame_id,
            info={**self.info, "world_scale": self.info.get("world_scale", 1.0) * factor},
        )


@dataclass(frozen=True)
class ClassMap:
    """External class ids <-> compact channels.

    Only classes present in the training masks get a channel ("model only what a scene
    requires"). Channel ``c`` stands for external id ``ids[c]``; ``ids`` is ascending.

    Attributes:
        ids: [C] int64 external class ids that own a channel.
        names: [C] class names.
        ignore_index: external label value that means "unlabelled", or None.
    """

    ids: np.ndarray
    names: tuple[str, ...]
    ignore_index: int | None = None

    def __post_init__(self) -> None:
        ids = np.asarray(self.ids, dtype=np.int64)
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "names", tuple(self.names))
        if ids.ndim != 1 or len(ids) == 0:
            raise InputError("a class map needs at least one class")
        if len(ids) != len(self.names):
            raise InputError(f"{len(ids)} class ids but {len(self.names)} names")
        if np.any(np.diff(ids) <= 0):
            raise InputError(f"class ids must be unique and ascending, got {ids.tolist()}")
        if self.ignore_index is not None and self.ignore_index in set(ids.tolist()):
            raise InputError(f"ignore_index {self.ignore_index} is also a class id")

    @property
    def num_classes(self) -> int:
        return len(self.ids)

    @staticmethod
    def unlabelled() -> "ClassMap":
        """The one-channel map of a scene without labels: every surface is class 0, "unlabelled"."""
        return ClassMap(ids=np.zeros(1, np.int64), names=(UNLABELLED_NAME,))

    @staticmethod
    def from_labels(
        labels: list[np.ndarray | None], classes: dict[int, str], ignore_index: int | None = None
    ) -> "ClassMap":
        """The classes of ``classes`` that occur in ``labels`` (ignore_index excluded)."""
        present: set[int] = set()
        for label in labels:
            if label is not None:
                present.update(np.unique(label).tolist())
        present.discard(ignore_index)
        unknown = sorted(present - set(classes))
        if unknown:
            raise InputError(f"label ids {unknown} are not in classes.json")
        if not present:
            raise InputError("no labelled pixel in the training views: at least one class is needed")
        ids = np.array(sorted(present), dtype=np.int64)
        return ClassMap(ids=ids, names=tuple(classes[i] for i in ids.tolist()), ignore_index=ignore_index)

    def channels_from_ids(self, labels: np.ndarray) -> np.ndarray:
        """Map external ids to channels; ignore_index (and ids without a channel) -> -1.

        Args:
            labels: int array of external ids, any shape.
        Returns:
            int64 array of the same shape with values in [-1, C).
        """
        labels = np.asarray(labels, dtype=np.int64)
        pos = np.searchsorted(self.ids, labels).clip(0, self.num_classes - 1)
        return np.where(self.ids[pos] == labels, pos, -1).astype(np.int64)

    def ids_from_channels(self, channels: np.ndarray) -> np.ndarray:
        """Map channels to external ids; negative values (FREE, UNKNOWN, ignore) pass through."""
        channels = np.asarray(channels, dtype=np.int64)
        return np.where(channels >= 0, self.ids[channels.clip(0, self.num_classes - 1)], channels)

    def to_dict(self) -> dict:
        return {"ids": self.ids.tolist(), "names": list(self.names), "ignore_index": self.ignore_index}

    @staticmethod
    def from_dict(data: dict) -> "ClassMap":
        return ClassMap(ids=np.asarray(data["ids"], np.int64), names=tuple(data["names"]), ignore_index=data.get("ignore_index"))
