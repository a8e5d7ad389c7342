"""Class vocabulary reduction: ``label_map.json`` maps a segmenter's source ids onto target classes.

A segmenter trained on ADE20K (150 classes) or Pascal-Context (59) labels a room with ids from its
own vocabulary; ``label_map.json`` in the scene folder (schema: scenelabel/schemas/label_map.schema.json)
says which source ids make which target class, e.g. ADE20K's ``chair`` and ``armchair`` -> ``seat``.
Source ids it does not map become unlabelled (ignore_index). Without the file, the vocabulary is
reduced anyway to the classes present in the training masks (:class:`scenelabel.ClassMap`).
Either way every output speaks external ids: the target ids here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenelabel.codes import FREE
from scenelabel.data.io.common import ClassesFile, classes_from_json, load_json, validate_json
from scenelabel.data.scene import Scene
from scenelabel.errors import InputError

__all__ = ["LABEL_MAP_FILE", "DEFAULT_IGNORE_INDEX", "LabelMap", "read_label_map", "apply_label_map"]

LABEL_MAP_FILE = "label_map.json"
DEFAULT_IGNORE_INDEX = 255
"""ignore_index after mapping when neither label_map.json nor classes.json gives one."""


@dataclass(frozen=True)
class LabelMap:
    """A parsed label_map.json.

    Attributes:
        target: the target vocabulary (classes, colours, ignore_index or None).
        mapping: source class id -> target class id.
        path: the file it came from.
    """

    target: ClassesFile
    mapping: dict[int, int]
    path: Path


def read_label_map(path: str | Path) -> LabelMap:
    """Read and validate ``label_map.json``.

    Raises:
        InputError naming the file and field: schema violations, duplicate target ids, a mapped-to
        id that is not a target class, ignore_index equal to a target id.
    """
    path = Path(path)
    data = load_json(path)
    validate_json(data, "label_map", path)
    target = classes_from_json(data, path)
    mapping = {int(src): int(dst) for src, dst in data["map"].items()}
    for src, dst in mapping.items():
        if dst not in target.classes:
            raise InputError(f"source id {src} maps to {dst}, which is not a target class id", path, field=f"$.map['{src}']")
    return LabelMap(target, mapping, path)


def apply_label_map(scene: Scene, label_map: LabelMap) -> Scene:
    """The scene with its labels and vocabulary mapped to the target classes.

    Args:
        scene: labels hold source ids (those of classes.json) or the scene's ignore_index.
        label_map: from :func:`read_label_map`; its map keys must be source class ids.
    Returns:
        a new Scene: labels int64 of target ids or the new ignore_index; classes, ignore_index and
        ``info["class_colors"]`` of the target vocabulary; ``info["label_map"]`` = the file's path.
    """
    stray = sorted(set(label_map.mapping) - set(scene.classes))
    if stray:
        raise InputError(
            f"maps source ids {stray[:10]} that are not in classes.json", label_map.path, field="$.map"
        )
    ignore = label_map.target.ignore_index
    if ignore is None:
        ignore = scene.ignore_index if scene.ignore_index is not None else DEFAULT_IGNORE_INDEX
    if ignore in label_map.target.classes:
        raise InputError(
            f"ignore_index {ignore} (from classes.json or the default) is also a target class id; set ignore_index",
            label_map.path, field="$.ignore_index",
        )
    labels = [None if lab is None else map_ids(lab, label_map.mapping, ignore) for lab in scene.labels]
    info = {**scene.info, "class_colors": dict(label_map.target.colors), "label_map": str(label_map.path)}
    return dataclasses.replace(
        scene, labels=labels, classes=dict(label_map.target.classes), ignore_index=ignore, info=info
    )


def map_ids(labels: np.ndarray, mapping: dict[int, int], unmapped: int) -> np.ndarray:
    """[...] int ids -> [...] int64 through ``mapping``; FREE stays FREE; ids it lacks (and other
    negatives) -> ``unmapped``."""
    labels = np.asarray(labels, dtype=np.int64)
    top = max(int(labels.max(initial=0)), max(mapping)) + 1
    lut = np.full(top, unmapped, dtype=np.int64)
    for src, dst in mapping.items():
        lut[src] = dst
    return np.where(labels >= 0, lut[labels.clip(0, top - 1)], np.where(labels == FREE, FREE, unmapped))
