"""Segmenters on torch.

- :class:`TorchSegmenter` wraps any ``torch.nn.Module`` returning per-class logits;
- :func:`torchvision_segmenter` builds one of torchvision's semantic segmentation models
  (DeepLabV3 / FCN / LR-ASPP, the 21 Pascal VOC classes) from a **local** weight file or the local
  torch hub cache.

Nothing here downloads anything: a missing weight file is an :class:`~scenelabel.errors.InputError`
that says where to put it.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from scenelabel.data.segmenters.common import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    VOC_CLASSES,
    as_triple,
    check_image,
    check_max_side,
    check_vocabulary,
    limited_size,
    logits_to_ids,
    resize_image,
    voc_colors,
)
from scenelabel.errors import InputError

__all__ = [
    "TORCHVISION_ARCHS",
    "TORCHVISION_WEIGHT_FILES",
    "TORCHVISION_MAX_SIDE",
    "TorchSegmenter",
    "torchvision_weights_path",
    "torchvision_segmenter",
]

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
        self.classes, ids = check_vocabulary(classes, channel_ids)
        self.channel_ids = ids
        self.ignore_index = ignore_index
        self.colors = dict(colors) if colors else {}
        self.max_side = check_max_side(max_side)
        self.device = torch.device(device if device is not None else ("cuda" if torch.cuda.is_available() else "cpu"))
        self.module = module.to(self.device).eval()
        self._mean = torch.from_numpy(as_triple(mean, "mean")).to(self.device).view(1, 3, 1, 1)
        self._std = torch.from_numpy(as_triple(std, "std")).to(self.device).view(1, 3, 1, 1)
        self._ids = torch.tensor(ids, dtype=torch.int64, device=self.device)
        parameter = next(iter(module.parameters()), None)
        self._dtype = parameter.dtype if parameter is not None and parameter.is_floating_point() else torch.float32

    def logits(self, image: np.ndarray) -> torch.Tensor:
        """The module's logits [C, h', w'] for one photo [h, w, 3] (after ``max_side`` shrinking)."""
        image = check_image(image)
        height, width = image.shape[:2]
        small = resize_image(image, *limited_size(width, height, self.max_side))
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
        image = check_image(image)
        with torch.inference_mode():
            return logits_to_ids(self.logits(image), image.shape[0], image.shape[1], self._ids)


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
