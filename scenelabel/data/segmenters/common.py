"""The segmenter protocol, its vocabulary and the image helpers every segmenter shares.

A :class:`Segmenter` maps one photo to a map of class ids and names its vocabulary.

Channel order: a model's output channel ``c`` stands for class id ``channel_ids[c]``; by default
the vocabulary's ids in ascending order (for the ONNX spec file: the order of its ``classes`` list).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from scenelabel.errors import InputError

__all__ = [
    "IMAGENET_MEAN",
    "IMAGENET_STD",
    "VOC_CLASSES",
    "Segmenter",
    "voc_colors",
    "check_vocabulary",
    "as_triple",
    "is_positive_int",
    "check_max_side",
    "check_image",
    "resize_image",
    "limited_size",
    "logits_to_ids",
]

#: ImageNet channel statistics (RGB, values in [0, 1]): the normalisation torchvision's models use.
IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)

#: The 21 Pascal VOC classes of torchvision's ``COCO_WITH_VOC_LABELS_V1`` weights (id = channel).
VOC_CLASSES: dict[int, str] = dict(
    enumerate(
        [
            "background", "aeroplane", "bicycle", "bird", "boat", "bottle", "bus", "car", "cat", "chair",
            "cow", "diningtable", "dog", "horse", "motorbike", "person", "pottedplant", "sheep", "sofa",
            "train", "tvmonitor",
        ]
    )
)

#: Elements of one band of full-resolution logits when resizing them (bounds the memory used).
_BAND_ELEMENTS = 1 << 24


# --------------------------------------------------------------------------------------------
# the protocol


@runtime_checkable
class Segmenter(Protocol):
    """Anything that labels a photo with class ids.

    Attributes:
        classes: external class id -> name, every id the segmenter may output (the vocabulary
            written to classes.json). Ids are integers in [0, 32767], names non-empty.
        ignore_index: an id it outputs for "no class" (written as classes.json's ``ignore_index``;
            must not be a class id), or None.

    An optional attribute ``colors`` (id -> (r, g, b), 0-255) is written to classes.json too.
    """

    classes: dict[int, str]
    ignore_index: int | None

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Label one photo.

        Args:
            image: float32 RGB in [0, 1], shape [h, w, 3].
        Returns:
            int64 [h, w]: a class id of ``classes`` (or ``ignore_index``) per pixel.
        """
        ...


def voc_colors(n: int = 256) -> dict[int, tuple[int, int, int]]:
    """The Pascal VOC palette: id -> (r, g, b) for ids 0..n-1 (1 -> (128, 0, 0), 15 -> (192, 128, 128))."""
    colors = {}
    for index in range(n):
        r = g = b = 0
        c = index
        for bit in range(8):
            r |= ((c >> 0) & 1) << (7 - bit)
            g |= ((c >> 1) & 1) << (7 - bit)
            b |= ((c >> 2) & 1) << (7 - bit)
            c >>= 3
        colors[index] = (r, g, b)
    return colors


def check_vocabulary(
    classes: Mapping[int, str], channel_ids: Sequence[int] | None, field: str = "classes"
) -> tuple[dict[int, str], list[int]]:
    """Normalised (classes, channel_ids): ids ints, channel_ids a permutation-free subset of ids."""
    if not isinstance(classes, Mapping) or not classes:
        raise InputError(f"must be a non-empty dict of class id -> name, got {classes!r:.80}", field=field)
    vocabulary = {}
    for key, name in classes.items():
        if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or not isinstance(name, str):
            raise InputError(f"must map integer class ids to names, got {key!r}: {name!r}", field=field)
        vocabulary[int(key)] = name
    ids = sorted(vocabulary) if channel_ids is None else [int(i) for i in channel_ids]
    unknown = [i for i in ids if i not in vocabulary]
    if unknown:
        raise InputError(f"channel ids {unknown[:10]} are not class ids of the vocabulary", field="channel_ids")
    if len(set(ids)) != len(ids):
        raise InputError("channel ids repeat an id", field="channel_ids")
    return vocabulary, ids


def as_triple(values: Sequence[float], field: str) -> np.ndarray:
    """Per-channel statistics as float32 [3] (finite; std also > 0)."""
    array = np.asarray(values, dtype=np.float64).reshape(-1)
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        raise InputError(f"must be 3 finite numbers (R, G, B), got {values!r}", field=field)
    if field == "std" and np.any(array <= 0):
        raise InputError(f"must be positive, got {values!r}", field=field)
    return array.astype(np.float32)


def is_positive_int(value: Any) -> bool:
    """Whether ``value`` is an integer >= 1 (not a bool)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 1


def check_max_side(max_side: int | None) -> int | None:
    """``max_side`` as an int >= 1 or None; InputError otherwise."""
    if max_side is None:
        return None
    if isinstance(max_side, bool) or not isinstance(max_side, (int, np.integer)) or max_side < 1:
        raise InputError(f"must be None or an integer >= 1, got {max_side!r}", field="max_side")
    return int(max_side)


def check_image(image: np.ndarray) -> np.ndarray:
    """``image`` as contiguous float32 [h, w, 3]; InputError for any other shape."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 1 or image.shape[1] < 1:
        raise InputError(f"image must be float RGB of shape [h, w, 3], got {list(image.shape)}", field="image")
    return np.ascontiguousarray(image, dtype=np.float32)


def resize_image(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """[h, w, 3] float32 resampled to [height, width, 3]: area when shrinking, bilinear otherwise."""
    h, w = image.shape[:2]
    if (w, h) == (width, height):
        return image
    shrink = width <= w and height <= h
    interpolation = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    return cv2.resize(image, (width, height), interpolation=interpolation).reshape(height, width, 3)


def limited_size(width: int, height: int, max_side: int | None) -> tuple[int, int]:
    """(width, height) scaled down so the longer side is at most ``max_side`` (never up)."""
    if max_side is None or max(width, height) <= max_side:
        return width, height
    scale = max_side / max(width, height)
    return max(1, round(width * scale)), max(1, round(height * scale))


def logits_to_ids(logits: torch.Tensor, height: int, width: int, channel_ids: torch.Tensor) -> np.ndarray:
    """Class ids of the argmax of logits resized bilinearly to [height, width].

    Same values as ``F.interpolate(logits[None], (height, width), mode="bilinear",
    align_corners=False)`` (pixel centres at +0.5), computed in bands of output rows so a big photo
    never holds all its full-resolution logits at once.

    Args:
        logits: [C, h', w'] float.
        height, width: output size.
        channel_ids: int64 [C], the class id of each channel (same device as logits).
    Returns:
        int64 [height, width] numpy array of class ids; ties go to the lower channel.
    """
    logits = logits.float()
    channels, h_in, w_in = logits.shape
    rows_per_band = max(1, _BAND_ELEMENTS // max(1, channels * width))
    out = torch.empty((height, width), dtype=torch.int64, device=logits.device)
    scale_y = h_in / height
    for start in range(0, height, rows_per_band):
        stop = min(height, start + rows_per_band)
        if h_in == height:
            band = logits[:, start:stop]
        else:
            rows = torch.arange(start, stop, device=logits.device, dtype=torch.float64)
            src = ((rows + 0.5) * scale_y - 0.5).clamp(min=0)
            y0 = src.floor().long().clamp(max=h_in - 1)
            y1 = (y0 + 1).clamp(max=h_in - 1)
            lam = (src - y0).float().clamp(max=1.0)[None, :, None]
            band = logits[:, y0] * (1 - lam) + logits[:, y1] * lam
        if w_in != width:
            band = F.interpolate(band[None], size=(stop - start, width), mode="bilinear", align_corners=False)[0]
        out[start:stop] = channel_ids[band.argmax(dim=0)]
    return out.cpu().numpy()
