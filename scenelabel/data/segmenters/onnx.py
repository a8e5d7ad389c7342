""":class:`OnnxSegmenter` runs an ONNX model through OpenCV's dnn module (no extra dependency)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np
import torch

from scenelabel.data.segmenters.common import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    as_triple,
    check_image,
    check_max_side,
    check_vocabulary,
    is_positive_int,
    limited_size,
    logits_to_ids,
    resize_image,
)
from scenelabel.errors import InputError

__all__ = ["OnnxSegmenter"]


class OnnxSegmenter:
    """A :class:`Segmenter` running an ONNX model with OpenCV's dnn module (``cv2.dnn``).

    The photo is resized (``input_size``, else shrunk to ``max_side``, else kept), normalised
    ``(rgb - mean) / std``, packed by ``cv2.dnn.blobFromImage`` into [1, 3, h, w] (R and B swapped
    when ``swap_rb``: the model wants BGR), and the model's first output, logits [1, C, h', w'], is
    resized bilinearly back to the photo's size before the argmax; channel ``c`` is class
    ``channel_ids[c]``.

    Args:
        path: the ``.onnx`` file.
        classes: class id -> name.
        channel_ids: the class id of each output channel; default: the ids in ascending order.
        input_size: (width, height) the model needs (fixed-shape exports), or None to feed the
            photo at its own size (models with dynamic height and width).
        mean, std: per-channel normalisation, RGB order, on values in [0, 1] (std = 1/255 and
            mean = 0 feed 0-255 values).
        swap_rb: feed BGR instead of RGB.
        max_side: with ``input_size`` None, shrink photos so the longer side is at most this.
        ignore_index, colors: written to classes.json, as for :class:`TorchSegmenter`.
    Raises:
        InputError: missing or unreadable model file (naming it).
    """

    def __init__(
        self,
        path: str | Path,
        classes: Mapping[int, str],
        *,
        channel_ids: Sequence[int] | None = None,
        input_size: tuple[int, int] | None = None,
        mean: Sequence[float] = IMAGENET_MEAN,
        std: Sequence[float] = IMAGENET_STD,
        swap_rb: bool = False,
        max_side: int | None = None,
        ignore_index: int | None = None,
        colors: Mapping[int, tuple[int, int, int]] | None = None,
    ):
        self.path = Path(path)
        self.classes, ids = check_vocabulary(classes, channel_ids)
        self.channel_ids = ids
        self.ignore_index = ignore_index
        self.colors = dict(colors) if colors else {}
        if input_size is not None:
            size = tuple(input_size)
            if len(size) != 2 or not all(is_positive_int(v) for v in size):
                raise InputError(f"must be (width, height), two integers >= 1, got {input_size!r}", field="input_size")
            input_size = (int(size[0]), int(size[1]))
        self.input_size = input_size
        self.max_side = check_max_side(max_side)
        self.mean = as_triple(mean, "mean")
        self.std = as_triple(std, "std")
        self.swap_rb = bool(swap_rb)
        self._ids = torch.tensor(ids, dtype=torch.int64)
        if not self.path.is_file():
            raise InputError("ONNX model file not found", self.path)
        try:
            self.net = cv2.dnn.readNetFromONNX(str(self.path))
        except cv2.error as error:
            problem = f"OpenCV's dnn module cannot read the ONNX model ({_cv_message(error)})"
            raise InputError(problem, self.path) from None

    def logits(self, image: np.ndarray) -> np.ndarray:
        """The model's logits float32 [C, h', w'] for one photo [h, w, 3]."""
        image = check_image(image)
        height, width = image.shape[:2]
        size = self.input_size or limited_size(width, height, self.max_side)
        normalised = (resize_image(image, *size) - self.mean) / self.std
        blob = cv2.dnn.blobFromImage(normalised, 1.0, size, (0.0, 0.0, 0.0), self.swap_rb, False)
        try:
            self.net.setInput(blob)
            out = self.net.forward()
        except cv2.error as error:
            hint = "; a model exported with a fixed input shape needs input_size=(width, height)"
            hint = "" if self.input_size else hint
            raise InputError(
                f"running the model on a {size[0]}x{size[1]} input failed ({_cv_message(error)}){hint}", self.path
            ) from None
        out = np.asarray(out)
        if out.ndim != 4 or out.shape[0] != 1:
            raise InputError(f"the model's first output must be logits [1, C, h, w], got {list(out.shape)}", self.path)
        if out.shape[1] != len(self.channel_ids):
            raise InputError(
                f"the model outputs {out.shape[1]} channels but the vocabulary has {len(self.channel_ids)} channel ids",
                self.path,
            )
        return np.ascontiguousarray(out[0], dtype=np.float32)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Class ids int64 [h, w] of a float32 RGB photo [h, w, 3] in [0, 1]."""
        image = check_image(image)
        logits = torch.from_numpy(self.logits(image))
        return logits_to_ids(logits, image.shape[0], image.shape[1], self._ids)


def _cv_message(error: cv2.error) -> str:
    """The informative line of an OpenCV error (its text spans several lines)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return (lines[-1] if lines else type(error).__name__)[:300]
