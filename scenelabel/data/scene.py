"""Scene data: cameras (:mod:`scenelabel.geometry.cameras`), images, label maps and the class map,
in scenelabel's conventions.

Every loader in :mod:`scenelabel.data.io` converts its input into these types; see docs/conventions.md.

- Cameras: ``c2w`` is camera-to-world with **OpenCV camera axes** (x right, y down, z forward),
  in the input's own world frame and units. Intrinsics in pixels; the centre of pixel (col, row)
  is at (col + 0.5, row + 0.5).
- Images: float32 RGB in [0, 1], shape [height, width, 3]; an alpha channel is kept beside them
  (``Scene.image_alphas``), not composited.
- Labels: int64 external class ids (those of classes.json), shape [height, width];
  ``ignore_index`` marks unlabelled pixels.
- Depths (ground truth for scoring, synthetic scenes only): distance along the unit ray direction.
- Sensor depths (measurements used for training: RGB-D cameras, phone LiDAR): distance along the
  unit ray of each colour pixel, world units, NaN where there is no measurement.
- Masks: bool [height, width], True = use the pixel, False = ignore it (nerfstudio ``mask_path``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenelabel.codes import FREE
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import Cameras

__all__ = ["Scene", "ClassMap", "UNLABELLED_NAME", "SILHOUETTE_ALPHA"]

#: Class name of the single channel of a build without labels (photometric only).
UNLABELLED_NAME = "unlabelled"

SILHOUETTE_ALPHA = 0.5
"""A pixel whose alpha is below this shows nothing: its ray meets nothing (:meth:`Scene.silhouettes`)."""


@dataclass
class Scene:
    """A loaded scene: cameras plus per-view images, optional labels and optional depths.

    Attributes:
        root: the scene folder.
        cameras: one camera per view.
        names: [n] view names (image file stems).
        images: n arrays [h, w, 3] float32 in [0, 1].
        labels: n arrays [h, w] int64 of external class ids (``ignore_index`` for an unlabelled pixel,
            FREE = -1 for a pixel whose ray meets nothing, classes.json's ``free_index``), or None for
            an unlabelled view.
        depths: n arrays [h, w] float32 ground-truth depth along the unit ray, or None.
        classes: the full vocabulary of classes.json: external id -> name.
        ignore_index: the label value of unlabelled pixels, or None.
        aabb: [2, 3] explicit scene bounds (min corner, max corner) from the input, or None.
        frame_id: name of the world frame (for exports).
        info: loader facts (format, source, ...), recorded in the checkpoint.
        sensor_depths: None (no sensor depth), or n arrays [h, w] float32 (distance along the unit ray
            of each colour pixel, world units, NaN = no measurement) or None per view. Training
            uses them (the depth loss); ``depths`` are only scored against.
        masks: None (every pixel used), or n arrays [h, w] bool (False: the pixel is ignored by every
            loss) or None per view.
        splits: None (the build holds out every ``train.holdout``-th view), or the input's own split:
            {"train": [...], "val": [...], "test": [...]} view indices (e.g. the Blender layout's
            transforms_train / _val / _test files).
        image_alphas: None (opaque images), or n arrays [h, w] float32 in [0, 1] (the image's alpha channel:
            the pixel's colour is ``rgb * alpha + background * (1 - alpha)``, the background being
            the build's ``train.background``) or None per view (an opaque image).
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
    sensor_depths: list[np.ndarray | None] | None = None
    masks: list[np.ndarray | None] | None = None
    splits: dict[str, list[int]] | None = None
    image_alphas: list[np.ndarray | None] | None = None

    def __len__(self) -> int:
        return len(self.cameras)

    def silhouettes(self, indices: list[int]) -> list[np.ndarray | None]:
        """Per view of ``indices``: [h, w] bool, True where the image shows something (alpha at least
        SILHOUETTE_ALPHA where the image has alpha, else a label other than FREE where the view's
        labels hold FREE), or None where the view does not say where nothing is."""
        out: list[np.ndarray | None] = []
        for i in indices:
            alpha = None if self.image_alphas is None else self.image_alphas[i]
            label = self.labels[i]
            if alpha is not None:
                out.append(alpha >= SILHOUETTE_ALPHA)
            elif label is not None and np.any(label == FREE):
                out.append(label != FREE)
            else:
                out.append(None)
        return out

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
            sensor_depths=None if self.sensor_depths is None else [
                None if d is None else d * np.float32(factor) for d in self.sensor_depths
            ],
            masks=self.masks,
            splits=self.splits,
            image_alphas=self.image_alphas,
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
        """The classes of ``classes`` that occur in ``labels`` (ignore_index and FREE excluded)."""
        present: set[int] = set()
        for label in labels:
            if label is not None:
                present.update(np.unique(label).tolist())
        present.discard(ignore_index)
        present.discard(FREE)
        unknown = sorted(present - set(classes))
        if unknown:
            raise InputError(f"label ids {unknown} are not in classes.json")
        if not present:
            raise InputError("no labelled pixel in the training views: at least one class is needed")
        ids = np.array(sorted(present), dtype=np.int64)
        return ClassMap(ids=ids, names=tuple(classes[i] for i in ids.tolist()), ignore_index=ignore_index)

    def channels_from_ids(self, labels: np.ndarray) -> np.ndarray:
        """Map external ids to channels; ignore_index, FREE (and ids without a channel) -> -1.

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
