"""2D segmenters: label masks for a scene folder that has none (``labels/`` absent).

A :class:`Segmenter` maps one photo to a map of class ids and names its vocabulary;
:func:`segment_scene` runs one over ``scene/images/`` and writes ``scene/labels/<stem>.png`` and
``scene/classes.json`` in the formats of docs/formats.md, so the user can inspect (and fix) the
masks before training on them. Built-ins:

- :class:`TorchSegmenter` wraps any ``torch.nn.Module`` returning per-class logits;
- :func:`torchvision_segmenter` builds one of torchvision's semantic segmentation models
  (DeepLabV3 / FCN / LR-ASPP, the 21 Pascal VOC classes) from a **local** weight file or the local
  torch hub cache;
- :class:`OnnxSegmenter` runs an ONNX model through OpenCV's dnn module (no extra dependency).

Nothing here downloads anything: a missing weight file is an :class:`~scenelabel.errors.InputError`
that says where to put it. :func:`load_segmenter` turns a spec string (the CLI's ``--model``) into
a segmenter; ``python:MODULE:ATTR`` plugs in the user's own model (docs/formats.md, "Segmenters").

Channel order: a model's output channel ``c`` stands for class id ``channel_ids[c]``; by default
the vocabulary's ids in ascending order (for the ONNX spec file: the order of its ``classes`` list).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from ._files import atomic_write_bytes
from .errors import InputError
from .io.common import (
    LABEL_SUFFIX,
    classes_from_json,
    list_images,
    load_json,
    read_image,
    validate_json,
)

__all__ = [
    "IMAGENET_MEAN",
    "IMAGENET_STD",
    "VOC_CLASSES",
    "TORCHVISION_ARCHS",
    "TORCHVISION_WEIGHT_FILES",
    "TORCHVISION_MAX_SIDE",
    "Segmenter",
    "TorchSegmenter",
    "OnnxSegmenter",
    "SegmentResult",
    "voc_colors",
    "torchvision_weights_path",
    "torchvision_segmenter",
    "check_segmenter",
    "load_segmenter",
    "segment_scene",
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

#: File names torchvision gives the ``COCO_WITH_VOC_LABELS_V1`` weights of each architecture (the
#: last part of the weights' URL, as in torchvision.models.segmentation's ``*_Weights`` enums);
#: torchvision caches them as ``torch.hub.get_dir()/checkpoints/<file name>``.
TORCHVISION_WEIGHT_FILES: dict[str, str] = {
    "deeplabv3_resnet50": "deeplabv3_resnet50_coco-cd0a2569.pth",
    "deeplabv3_resnet101": "deeplabv3_resnet101_coco-586e9e4e.pth",
    "deeplabv3_mobilenet_v3_large": "deeplabv3_mobilenet_v3_large-fc3c493d.pth",
    "fcn_resnet50": "fcn_resnet50_coco-1167a1af.pth",
    "fcn_resnet101": "fcn_resnet101_coco-7ecb50ca.pth",
    "lraspp_mobilenet_v3_large": "lraspp_mobilenet_v3_large-d234d4ea.pth",
}

#: Architectures :func:`torchvision_segmenter` builds (functions of torchvision.models.segmentation).
TORCHVISION_ARCHS: tuple[str, ...] = tuple(TORCHVISION_WEIGHT_FILES)

#: Default longest side (pixels) photos are shrunk to before a torchvision model sees them: the
#: models were trained with a shorter side of 520, and full-size photos cost memory and accuracy.
TORCHVISION_MAX_SIDE = 1024

#: Elements of one band of full-resolution logits when resizing them (bounds the memory used).
_BAND_ELEMENTS = 1 << 24

#: Largest id a 16-bit label PNG holds.
_MAX_16BIT_ID = 65535

_SPEC_FORMS = (
    "torchvision:ARCH[:WEIGHTS.pth], onnx:MODEL.onnx:CLASSES.json or python:MODULE:ATTR "
    "(MODULE a dotted module name or a .py file)"
)


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


def _check_vocabulary(
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


def _as_triple(values: Sequence[float], field: str) -> np.ndarray:
    """Per-channel statistics as float32 [3] (finite; std also > 0)."""
    array = np.asarray(values, dtype=np.float64).reshape(-1)
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        raise InputError(f"must be 3 finite numbers (R, G, B), got {values!r}", field=field)
    if field == "std" and np.any(array <= 0):
        raise InputError(f"must be positive, got {values!r}", field=field)
    return array.astype(np.float32)


def _is_positive_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 1


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_max_side(max_side: int | None) -> int | None:
    if max_side is None:
        return None
    if isinstance(max_side, bool) or not isinstance(max_side, (int, np.integer)) or max_side < 1:
        raise InputError(f"must be None or an integer >= 1, got {max_side!r}", field="max_side")
    return int(max_side)


def _check_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 1 or image.shape[1] < 1:
        raise InputError(f"image must be float RGB of shape [h, w, 3], got {list(image.shape)}", field="image")
    return np.ascontiguousarray(image, dtype=np.float32)


def _resize_image(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """[h, w, 3] float32 resampled to [height, width, 3]: area when shrinking, bilinear otherwise."""
    h, w = image.shape[:2]
    if (w, h) == (width, height):
        return image
    shrink = width <= w and height <= h
    interpolation = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    return cv2.resize(image, (width, height), interpolation=interpolation).reshape(height, width, 3)


def _limited_size(width: int, height: int, max_side: int | None) -> tuple[int, int]:
    """(width, height) scaled down so the longer side is at most ``max_side`` (never up)."""
    if max_side is None or max(width, height) <= max_side:
        return width, height
    scale = max_side / max(width, height)
    return max(1, round(width * scale)), max(1, round(height * scale))


def _logits_to_ids(logits: torch.Tensor, height: int, width: int, channel_ids: torch.Tensor) -> np.ndarray:
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


# --------------------------------------------------------------------------------------------
# torch


class TorchSegmenter:
    """A :class:`Segmenter` around a ``torch.nn.Module`` that returns per-class logits.

    The module maps a normalised image batch [1, 3, h, w] (float, ``(rgb - mean) / std``) to
    logits [1, C, h', w'], or to a mapping whose ``"out"`` entry is that tensor (torchvision's
    segmentation models). Logits of any size (a stride that does not divide the image) are
    resized bilinearly to [h, w] before the argmax; channel ``c`` is class ``channel_ids[c]``.

    Args:
        module: the model; put in eval mode and moved to ``device``.
        classes: class id -> name, the vocabulary (C entries used by ``channel_ids``).
        channel_ids: the class id of each output channel; default: the ids in ascending order.
        mean, std: per-channel normalisation (RGB, on values in [0, 1]).
        device: torch device; default CUDA when available, else CPU.
        max_side: shrink photos (area resampling) so their longer side is at most this before
            inference; the ids are still returned at the photo's size. None: full size.
        ignore_index: id for "no class" written to classes.json (the model itself never outputs it).
        colors: optional id -> (r, g, b) display colours for classes.json.
    """

    def __init__(
        self,
        module: torch.nn.Module,
        classes: Mapping[int, str],
        *,
        channel_ids: Sequence[int] | None = None,
        mean: Sequence[float] = IMAGENET_MEAN,
        std: Sequence[float] = IMAGENET_STD,
        device: str | torch.device | None = None,
        max_side: int | None = None,
        ignore_index: int | None = None,
        colors: Mapping[int, tuple[int, int, int]] | None = None,
    ):
        if not isinstance(module, torch.nn.Module):
            raise InputError(f"must be a torch.nn.Module, got {type(module).__name__}", field="module")
        self.classes, ids = _check_vocabulary(classes, channel_ids)
        self.channel_ids = ids
        self.ignore_index = ignore_index
        self.colors = dict(colors) if colors else {}
        self.max_side = _check_max_side(max_side)
        self.device = torch.device(device if device is not None else ("cuda" if torch.cuda.is_available() else "cpu"))
        self.module = module.to(self.device).eval()
        self._mean = torch.from_numpy(_as_triple(mean, "mean")).to(self.device).view(1, 3, 1, 1)
        self._std = torch.from_numpy(_as_triple(std, "std")).to(self.device).view(1, 3, 1, 1)
        self._ids = torch.tensor(ids, dtype=torch.int64, device=self.device)
        parameter = next(iter(module.parameters()), None)
        self._dtype = parameter.dtype if parameter is not None and parameter.is_floating_point() else torch.float32

    def logits(self, image: np.ndarray) -> torch.Tensor:
        """The module's logits [C, h', w'] for one photo [h, w, 3] (after ``max_side`` shrinking)."""
        image = _check_image(image)
        height, width = image.shape[:2]
        small = _resize_image(image, *_limited_size(width, height, self.max_side))
        batch = torch.from_numpy(small).to(self.device).permute(2, 0, 1)[None]
        batch = ((batch - self._mean) / self._std).to(self._dtype)
        with torch.inference_mode():
            out = self.module(batch)
        if isinstance(out, Mapping):
            if "out" not in out:
                raise InputError(f"the module returned a mapping without 'out' (keys {list(out)[:5]})", field="module")
            out = out["out"]
        if not isinstance(out, torch.Tensor) or out.ndim != 4 or out.shape[0] != 1:
            shape = list(out.shape) if isinstance(out, torch.Tensor) else type(out).__name__
            raise InputError(f"the module must return logits [1, C, h, w], got {shape}", field="module")
        if out.shape[1] != len(self.channel_ids):
            raise InputError(
                f"the module returned {out.shape[1]} channels but the vocabulary has {len(self.channel_ids)} "
                f"channel ids", field="classes"
            )
        return out[0]

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Class ids int64 [h, w] of a float32 RGB photo [h, w, 3] in [0, 1]."""
        image = _check_image(image)
        with torch.inference_mode():
            return _logits_to_ids(self.logits(image), image.shape[0], image.shape[1], self._ids)


def torchvision_weights_path(arch: str) -> Path:
    """Where the torchvision weights of ``arch`` are looked for: the torch hub cache,
    ``torch.hub.get_dir()/checkpoints/<TORCHVISION_WEIGHT_FILES[arch]>`` (``$TORCH_HOME/hub/...``,
    by default ``~/.cache/torch/hub/checkpoints/...``), where torchvision itself caches them."""
    _check_arch(arch)
    return Path(torch.hub.get_dir()) / "checkpoints" / TORCHVISION_WEIGHT_FILES[arch]


def _check_arch(arch: str) -> None:
    if arch not in TORCHVISION_WEIGHT_FILES:
        choices = ", ".join(TORCHVISION_ARCHS)
        raise InputError(f"unknown torchvision architecture {arch!r}; choose one of {choices}", field="arch")


def _import_torchvision_segmentation() -> Any:
    """``torchvision.models.segmentation``, imported only now; InputError saying how to install it."""
    try:
        return importlib.import_module("torchvision.models.segmentation")
    except Exception as error:  # noqa: BLE001 - a broken install raises RuntimeError, not ImportError
        raise InputError(
            f"the torchvision segmenter needs torchvision, which cannot be imported ({type(error).__name__}: "
            f"{error}); install the torchvision release built for your torch {torch.__version__} "
            "(pip install torchvision, same index and CUDA variant as torch), or use an ONNX model "
            "(--model onnx:MODEL.onnx:CLASSES.json)",
            field="torchvision",
        ) from None


def _read_state_dict(path: Path) -> dict[str, torch.Tensor]:
    """A checkpoint's state dict: plain, or under ``model`` / ``state_dict``; DDP ``module.`` stripped."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # noqa: BLE001 - pickle, zip and torch errors alike
        problem = f"cannot read the weights as a torch state dict ({type(error).__name__}: {error})"
        raise InputError(problem, path) from None
    for key in ("model", "state_dict"):
        if isinstance(state, Mapping) and isinstance(state.get(key), Mapping):
            state = state[key]
    if not isinstance(state, Mapping) or not state or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError("the file holds no state dict of tensors (name -> tensor)", path)
    state = dict(state)
    if all(key.startswith("module.") for key in state):
        state = {key[len("module."):]: value for key, value in state.items()}
    return state


def torchvision_segmenter(
    arch: str,
    weights: str | Path | None = None,
    num_classes: int = 21,
    *,
    classes: Mapping[int, str] | None = None,
    device: str | torch.device | None = None,
    max_side: int | None = TORCHVISION_MAX_SIDE,
) -> TorchSegmenter:
    """A torchvision semantic segmentation model with local weights, as a :class:`TorchSegmenter`.

    torchvision is imported only here. The model is built with ``weights=None,
    weights_backbone=None`` (so torchvision downloads nothing), ``num_classes`` and ``aux_loss``
    when the checkpoint has an auxiliary head (DeepLabV3 / FCN), then the state dict is loaded.

    Args:
        arch: one of :data:`TORCHVISION_ARCHS`.
        weights: a ``.pth`` state dict (plain, or under ``model`` / ``state_dict`` as torchvision's
            training references save it); None: torchvision's ``COCO_WITH_VOC_LABELS_V1`` weights
            in the local torch hub cache (:func:`torchvision_weights_path`).
        num_classes: output channels of the checkpoint (21 for the VOC weights).
        classes: id -> name of channels 0..num_classes-1 in order; default: the Pascal VOC
            names (:data:`VOC_CLASSES`) for 21 classes, else ``class_0``, ``class_1``, ...
        device: torch device; default CUDA when available, else CPU.
        max_side: longest side photos are shrunk to before inference (None: full size).
    Raises:
        InputError: unknown arch, torchvision not importable, missing or unreadable weights
            (saying where to put them), weights that do not fit the architecture.
    """
    _check_arch(arch)
    if isinstance(num_classes, bool) or not isinstance(num_classes, (int, np.integer)) or num_classes < 1:
        raise InputError(f"must be an integer >= 1, got {num_classes!r}", field="num_classes")
    if classes is None:
        if num_classes == len(VOC_CLASSES):
            vocabulary = dict(VOC_CLASSES)
        else:
            vocabulary = {i: f"class_{i}" for i in range(num_classes)}
    else:
        vocabulary = dict(classes)
        if len(vocabulary) != num_classes:
            raise InputError(f"has {len(vocabulary)} classes but num_classes is {num_classes}", field="classes")
    colors = voc_colors(len(VOC_CLASSES)) if vocabulary == VOC_CLASSES else None
    segmentation = _import_torchvision_segmentation()

    if weights is None:
        path = torchvision_weights_path(arch)
        if not path.is_file():
            name = TORCHVISION_WEIGHT_FILES[arch]
            raise InputError(
                f"no local weights for {arch}: put torchvision's file {name} at this path (scenelabel never "
                f"downloads). On a machine with network access, run python -c \"import torchvision; "
                f"torchvision.models.segmentation.{arch}(weights='COCO_WITH_VOC_LABELS_V1')\", which saves "
                f"{name} in that machine's torch hub cache (~/.cache/torch/hub/checkpoints/); copy it here, "
                f"or pass its path: --model torchvision:{arch}:/path/to/{name}",
                path,
            )
    else:
        path = Path(weights)
        if not path.is_file():
            raise InputError(f"weights file for {arch} not found", path)
    state = _read_state_dict(path)

    kwargs: dict[str, Any] = {"weights": None, "weights_backbone": None, "num_classes": int(num_classes)}
    if not arch.startswith("lraspp"):  # LR-ASPP has no auxiliary head and refuses aux_loss=True
        kwargs["aux_loss"] = any(key.startswith("aux_classifier.") for key in state)
    model = getattr(segmentation, arch)(**kwargs)
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as error:
        detail = " ".join(str(error).split())
        raise InputError(
            f"the weights do not fit torchvision's {arch} with num_classes={num_classes}: {detail[:400]}", path
        ) from None
    return TorchSegmenter(model, vocabulary, device=device, max_side=max_side, colors=colors)


# --------------------------------------------------------------------------------------------
# ONNX through OpenCV dnn


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
        self.classes, ids = _check_vocabulary(classes, channel_ids)
        self.channel_ids = ids
        self.ignore_index = ignore_index
        self.colors = dict(colors) if colors else {}
        if input_size is not None:
            size = tuple(input_size)
            if len(size) != 2 or not all(_is_positive_int(v) for v in size):
                raise InputError(f"must be (width, height), two integers >= 1, got {input_size!r}", field="input_size")
            input_size = (int(size[0]), int(size[1]))
        self.input_size = input_size
        self.max_side = _check_max_side(max_side)
        self.mean = _as_triple(mean, "mean")
        self.std = _as_triple(std, "std")
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
        image = _check_image(image)
        height, width = image.shape[:2]
        size = self.input_size or _limited_size(width, height, self.max_side)
        normalised = (_resize_image(image, *size) - self.mean) / self.std
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
        image = _check_image(image)
        logits = torch.from_numpy(self.logits(image))
        return _logits_to_ids(logits, image.shape[0], image.shape[1], self._ids)


def _cv_message(error: cv2.error) -> str:
    """The informative line of an OpenCV error (its text spans several lines)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return (lines[-1] if lines else type(error).__name__)[:300]


# --------------------------------------------------------------------------------------------
# spec strings


def check_segmenter(segmenter: Any, source: str = "segmenter") -> Segmenter:
    """Check that ``segmenter`` has a usable ``classes`` vocabulary, ``ignore_index`` and ``__call__``.

    A missing ``ignore_index`` attribute counts as None. Returns the segmenter.

    Raises:
        InputError: naming ``source`` (e.g. the spec string) and the problem.
    """
    if not callable(segmenter):
        raise InputError(f"is not callable (image -> class ids): {type(segmenter).__name__}", field=source)
    classes = getattr(segmenter, "classes", None)
    if not isinstance(classes, Mapping) or not classes:
        raise InputError("needs a non-empty `classes` dict of class id -> name", field=source)
    for key, name in classes.items():
        if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or not isinstance(name, str):
            raise InputError(f"`classes` must map integer ids to names, got {key!r}: {name!r}", field=source)
    ignore = getattr(segmenter, "ignore_index", None)
    if ignore is not None and (isinstance(ignore, bool) or not isinstance(ignore, (int, np.integer))):
        raise InputError(f"`ignore_index` must be an integer or None, got {ignore!r}", field=source)
    return segmenter


def _onnx_from_spec(model: Path, classes_path: Path) -> OnnxSegmenter:
    """An OnnxSegmenter from a classes.json-style file with an optional ``preprocess`` object."""
    data = load_json(classes_path)
    validate_json(data, "classes", classes_path)
    vocabulary = classes_from_json(data, classes_path)
    channel_ids = [int(entry["id"]) for entry in data["classes"]]
    options = data.get("preprocess", {})
    if not isinstance(options, dict):
        raise InputError("must be an object", classes_path, field="$.preprocess")
    known = ("input_size", "mean", "std", "swap_rb", "max_side")
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise InputError(f"unknown keys {unknown}; known: {sorted(known)}", classes_path, field="$.preprocess")
    checks = {
        "mean": (lambda v: isinstance(v, list) and len(v) == 3 and all(_is_number(x) for x in v),
                 "3 numbers (R, G, B)"),
        "std": (lambda v: isinstance(v, list) and len(v) == 3 and all(_is_number(x) and x > 0 for x in v),
                "3 positive numbers (R, G, B)"),
        "input_size": (lambda v: isinstance(v, list) and len(v) == 2 and all(_is_positive_int(x) for x in v),
                       "[width, height], integers >= 1"),
        "swap_rb": (lambda v: isinstance(v, bool), "true or false"),
        "max_side": (lambda v: v is None or _is_positive_int(v), "an integer >= 1 or null"),
    }
    kwargs: dict[str, Any] = {}
    for key, value in options.items():
        valid, wanted = checks[key]
        if not valid(value):
            raise InputError(f"must be {wanted}, got {value!r}", classes_path, field=f"$.preprocess.{key}")
        kwargs[key] = tuple(value) if key == "input_size" else value
    return OnnxSegmenter(
        model, vocabulary.classes, channel_ids=channel_ids, ignore_index=vocabulary.ignore_index,
        colors=vocabulary.colors, **kwargs,
    )


def _python_object(module_part: str, attr: str, spec: str) -> Any:
    """``attr`` (dotted) of a module given by dotted name or by a ``.py`` file path."""
    if module_part.endswith(".py"):
        path = Path(module_part)
        if not path.is_file():
            raise InputError("Python file of the segmenter not found", path)
        name = f"_scenelabel_user_segmenter_{abs(hash(str(path.resolve())))}"
        spec_obj = importlib.util.spec_from_file_location(name, path)
        if spec_obj is None or spec_obj.loader is None:
            raise InputError("cannot load this file as a Python module", path)
        module = importlib.util.module_from_spec(spec_obj)
        sys.modules[name] = module
        try:
            spec_obj.loader.exec_module(module)
        except BaseException:
            sys.modules.pop(name, None)
            raise
    else:
        try:
            module = importlib.import_module(module_part)
        except ModuleNotFoundError as error:
            if error.name and module_part.startswith(error.name):
                problem = f"no module named {module_part!r} (is it installed or on PYTHONPATH?)"
                raise InputError(problem, field=spec) from None
            raise
    obj: Any = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise InputError(f"{module_part} has no attribute {attr!r}", field=spec)
        obj = getattr(obj, part)
    return obj


def load_segmenter(spec: str, device: str | torch.device | None = None) -> Segmenter:
    """A segmenter from a spec string (the CLI's ``--model``).

    ``device`` (torch device, default CUDA when available) applies to ``torchvision:`` specs;
    ONNX models run on OpenCV's CPU backend, and ``python:`` segmenters choose their own.

    Forms:

    - ``torchvision:ARCH`` / ``torchvision:ARCH:WEIGHTS.pth``: :func:`torchvision_segmenter` (weights
      from the torch hub cache, or that file);
    - ``onnx:MODEL.onnx:CLASSES.json``: :class:`OnnxSegmenter`. CLASSES.json has the classes.json
      format, its ``classes`` list **in the model's channel order** (entry c = output channel c),
      plus an optional ``"preprocess"`` object with ``input_size`` [w, h], ``mean`` and ``std``
      (RGB, on [0, 1] values; default ImageNet's), ``swap_rb`` (bool), ``max_side`` (int);
    - ``python:MODULE:ATTR``: the user's own segmenter. MODULE is a dotted module name or a
      ``.py`` file; ATTR names a segmenter object (it has ``classes``), or a class or function
      called with no arguments that returns one.

    Raises:
        InputError: an unknown form, missing files, or an object that is not a segmenter.
    """
    if not isinstance(spec, str) or ":" not in spec:
        raise InputError(f"unknown segmenter spec {spec!r}; expected {_SPEC_FORMS}", field="--model")
    kind, rest = spec.split(":", 1)
    if kind == "torchvision":
        arch, _, weights = rest.partition(":")
        return torchvision_segmenter(arch, weights or None, device=device)
    if kind == "onnx":
        model, sep, classes_file = rest.rpartition(":")
        if not sep or not model or not classes_file:
            raise InputError(f"expected onnx:MODEL.onnx:CLASSES.json, got {spec!r}", field="--model")
        return _onnx_from_spec(Path(model), Path(classes_file))
    if kind == "python":
        module_part, sep, attr = rest.rpartition(":")
        if not sep or not module_part or not attr:
            raise InputError(f"expected python:MODULE:ATTR, got {spec!r}", field="--model")
        obj = _python_object(module_part, attr, spec)
        if not isinstance(obj, type) and hasattr(obj, "classes"):
            return check_segmenter(obj, spec)
        if not callable(obj):
            raise InputError(f"{attr!r} is neither a segmenter nor a factory returning one", field=spec)
        try:
            inspect.signature(obj).bind()
        except TypeError as error:
            problem = f"{attr!r} is called with no arguments to make the segmenter, but {error}"
            raise InputError(problem, field=spec) from None
        except ValueError:  # builtins without a signature: just call them
            pass
        segmenter = obj()
        return check_segmenter(segmenter, spec)
    raise InputError(f"unknown segmenter kind {kind!r}; expected {_SPEC_FORMS}", field="--model")


# --------------------------------------------------------------------------------------------
# writing labels/ and classes.json


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
