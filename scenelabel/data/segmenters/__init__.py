"""2D segmenters: label masks for a scene folder that has none (``labels/`` absent).

A :class:`Segmenter` maps one photo to a map of class ids and names its vocabulary;
:func:`segment_scene` runs one over ``scene/images/`` and writes ``scene/labels/<stem>.png`` and
``scene/classes.json`` in the formats of docs/formats.md. Built-ins: :class:`TorchSegmenter`,
:func:`torchvision_segmenter` (local weights only) and :class:`OnnxSegmenter`; :func:`load_segmenter`
turns a spec string (the CLI's ``--model``) into a segmenter.

Modules: ``common`` (the protocol, vocabulary and image helpers), ``torch_models`` (torch and
torchvision), ``onnx`` (OpenCV dnn), ``loading`` (spec strings) and ``scene`` (writing labels/).
"""

from __future__ import annotations

from scenelabel.data.segmenters.common import IMAGENET_MEAN, IMAGENET_STD, VOC_CLASSES, Segmenter, voc_colors
from scenelabel.data.segmenters.loading import check_segmenter, load_segmenter
from scenelabel.data.segmenters.onnx import OnnxSegmenter
from scenelabel.data.segmenters.scene import SegmentResult, segment_scene
from scenelabel.data.segmenters.torch_models import (
    TORCHVISION_ARCHS,
    TORCHVISION_MAX_SIDE,
    TORCHVISION_WEIGHT_FILES,
    TorchSegmenter,
    torchvision_segmenter,
    torchvision_weights_path,
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
