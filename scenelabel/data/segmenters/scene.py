"""Writing ``labels/`` and ``classes.json`` for a scene folder that has none.

:func:`segment_scene` runs a :class:`Segmenter` over ``scene/images/`` and writes
``scene/labels/<stem>.png`` and ``scene/classes.json`` in the formats of docs/formats.md, so the
user can inspect (and fix) the masks before training on them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from scenelabel._files import atomic_write_bytes
from scenelabel.data.io.common import LABEL_SUFFIX, classes_from_json, list_images, read_image, validate_json
from scenelabel.data.segmenters.common import Segmenter
from scenelabel.data.segmenters.loading import check_segmenter
from scenelabel.errors import InputError

__all__ = ["SegmentResult", "segment_scene"]

#: Largest id a 16-bit label PNG holds.
_MAX_16BIT_ID = 65535


@dataclass(frozen=True)
class SegmentResult:
    """What :func:`segment_scene` wrote.

    Attributes:
        labels_dir: ``scene/labels``.
        classes_path: ``scene/classes.json``.
        label_paths: one label PNG per image of ``scene/images``, in image order.
        counts: pixels per id over all images: every class id of the vocabulary (0 when absent),
            plus ``ignore_index`` when the segmenter has one; ascending ids.
    """

    labels_dir: Path
    classes_path: Path
    label_paths: tuple[Path, ...]
    counts: dict[int, int]


def _classes_document(segmenter: Segmenter, path: Path) -> dict:
    """classes.json content of the segmenter's vocabulary, validated like read_classes does."""
    colors = getattr(segmenter, "colors", None) or {}
    entries = []
    for class_id in sorted(int(i) for i in segmenter.classes):
        entry: dict[str, Any] = {"id": class_id, "name": segmenter.classes[class_id]}
        if class_id in colors:
            entry["color"] = [int(c) for c in colors[class_id]]
        entries.append(entry)
    data: dict[str, Any] = {"classes": entries}
    ignore = getattr(segmenter, "ignore_index", None)
    if ignore is not None:
        data["ignore_index"] = int(ignore)
    try:
        validate_json(data, "classes", path)
        classes_from_json(data, path)
    except InputError as error:
        problem = f"the segmenter's vocabulary cannot be written as classes.json: {error.problem}"
        raise InputError(problem, path, error.field) from None
    return data


def _encode_png(label: np.ndarray, dtype: type) -> bytes:
    ok, buffer = cv2.imencode(LABEL_SUFFIX, label.astype(dtype))
    if not ok:  # pragma: no cover - OpenCV encodes any uint8/uint16 single-channel array
        raise RuntimeError("OpenCV could not encode a label PNG")
    return buffer.tobytes()


def segment_scene(
    scene_dir: str | Path, segmenter: Segmenter, overwrite: bool = False, progress: bool = True
) -> SegmentResult:
    """Label every photo of ``scene_dir/images/`` and write ``labels/`` and ``classes.json``.

    Writes ``labels/<image stem>.png`` (single channel, the segmenter's class ids; 8-bit when every
    id and ``ignore_index`` is below 256, else 16-bit) and then ``classes.json`` with the whole
    vocabulary (``id``, ``name``, ``color`` when the segmenter has ``colors``, ``ignore_index`` when
    not None). Every file is written atomically; classes.json comes last, so its presence marks a
    finished run.

    Args:
        scene_dir: the scene folder.
        segmenter: a :class:`Segmenter`.
        overwrite: replace label files in an existing non-empty ``labels/`` and a classes.json
            with a different vocabulary; otherwise either is refused.
        progress: show a tqdm progress bar.
    Returns:
        :class:`SegmentResult` with per-id pixel counts.
    Raises:
        InputError: no ``images/`` or no image in it, two images with one stem, existing labels
            or classes.json without ``overwrite``, a vocabulary classes.json cannot hold, or a
            segmenter output of the wrong shape or with ids outside its vocabulary.
    """
    root = Path(scene_dir)
    images_dir = root / "images"
    labels_dir = root / "labels"
    classes_path = root / "classes.json"
    check_segmenter(segmenter)
    if not images_dir.is_dir():
        raise InputError("no images/ folder: segment_scene labels the photos of scene/images/", images_dir)
    images = list_images(images_dir)
    if not images:
        raise InputError("no PNG or JPEG image in the folder", images_dir)
    stems: dict[str, Path] = {}
    for image in images:
        if image.stem in stems:
            problem = f"{stems[image.stem].name} and {image.name} would share the label file {image.stem}{LABEL_SUFFIX}"
            raise InputError(problem, images_dir)
        stems[image.stem] = image

    document = _classes_document(segmenter, classes_path)
    if not overwrite:
        if labels_dir.is_dir() and any(labels_dir.iterdir()):
            raise InputError(
                "labels/ already exists and is not empty; pass overwrite=True (--overwrite) to replace its masks",
                labels_dir,
            )
        if classes_path.exists():
            try:
                same = json.loads(classes_path.read_text(encoding="utf-8")) == document
            except (OSError, UnicodeDecodeError, json.JSONDecodeError):
                same = False
            if not same:
                raise InputError(
                    "classes.json already exists with another vocabulary; "
                    "pass overwrite=True (--overwrite) to replace it",
                    classes_path,
                )

    ignore = getattr(segmenter, "ignore_index", None)
    allowed = np.array(sorted({int(i) for i in segmenter.classes} | (set() if ignore is None else {int(ignore)})))
    dtype = np.uint8 if allowed.max() < 256 else np.uint16
    counts = np.zeros(max(int(allowed.max()) + 1, 1), dtype=np.int64)
    labels_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for image_path in tqdm(images, disable=not progress, unit="image", desc="segmenting", dynamic_ncols=True):
        image = read_image(image_path)
        ids = np.asarray(segmenter(image))
        if ids.shape != image.shape[:2]:
            problem = f"the segmenter returned shape {list(ids.shape)} for an image of shape {list(image.shape[:2])}"
            raise InputError(problem + " ([h, w])", image_path)
        if not np.issubdtype(ids.dtype, np.integer):
            raise InputError(f"the segmenter returned dtype {ids.dtype}; class ids must be integers", image_path)
        present = np.unique(ids)
        stray = present[~np.isin(present, allowed)]
        if stray.size:
            problem = f"the segmenter returned ids {stray[:10].tolist()} that are not in its vocabulary"
            raise InputError(problem, image_path)
        counts += np.bincount(ids.reshape(-1).astype(np.int64), minlength=counts.size)
        out = labels_dir / f"{image_path.stem}{LABEL_SUFFIX}"
        atomic_write_bytes(out, _encode_png(ids, dtype))
        written.append(out)
    atomic_write_bytes(classes_path, (json.dumps(document, indent=2) + "\n").encode("utf-8"))
    return SegmentResult(
        labels_dir=labels_dir,
        classes_path=classes_path,
        label_paths=tuple(written),
        counts={int(i): int(counts[i]) for i in allowed},
    )
