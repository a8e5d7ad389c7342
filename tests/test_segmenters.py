"""2D segmenters (scenelabel.data.segmenters): torch modules, torchvision models (through a fake
torchvision package: the real one is not importable here and no weights are downloaded), ONNX
models through OpenCV dnn, spec strings, and writing labels/ + classes.json for a scene."""

from __future__ import annotations

import json
import shutil
import sys
import types
from collections import OrderedDict
from pathlib import Path

import numpy as np
import onnx  # a test dependency (pyproject [test]) to build tiny models; scenelabel reads ONNX with OpenCV
import pytest
import torch
import torch.nn.functional as F
from onnx import TensorProto, helper, numpy_helper
from PIL import Image

from scenelabel.data.io.common import read_classes, read_label
from scenelabel.data.segmenters import (
    TORCHVISION_ARCHS,
    TORCHVISION_WEIGHT_FILES,
    VOC_CLASSES,
    OnnxSegmenter,
    Segmenter,
    TorchSegmenter,
    load_segmenter,
    segment_scene,
    torchvision_segmenter,
    torchvision_weights_path,
    voc_colors,
)
from scenelabel.data.segmenters.common import logits_to_ids
from scenelabel.errors import InputError

# A linear pixel classifier with hand-computable output: logits = W @ rgb + b.
# Grey v: class 0 when v < 0.5 (dark), class 1 when v > 0.5 (bright); saturated red: class 2.
W = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [2.0, -1.0, -1.0]], dtype=np.float32)
B = np.array([1.5, -1.5, 0.0], dtype=np.float32)
ZERO, ONE = (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)


def expected_channels(image: np.ndarray, mean=ZERO, std=ONE) -> np.ndarray:
    """Argmax of the linear classifier on normalised pixels, in numpy (float64)."""
    x = (image.astype(np.float64) - np.asarray(mean)) / np.asarray(std)
    return np.argmax(x @ W.T.astype(np.float64) + B, axis=-1)


def linear_conv(out_channels: int = 3) -> torch.nn.Conv2d:
    conv = torch.nn.Conv2d(3, out_channels, 1)
    with torch.no_grad():
        conv.weight.copy_(torch.from_numpy(W[:out_channels]).view(out_channels, 3, 1, 1))
        conv.bias.copy_(torch.from_numpy(B[:out_channels]))
    return conv


def blocky_image(height: int, width: int, block: int, seed: int = 0) -> np.ndarray:
    """An image of constant block x block tiles of dark grey, light grey and red (clear margins)."""
    rng = np.random.default_rng(seed)
    palette = np.array([[0.1, 0.1, 0.1], [0.9, 0.9, 0.9], [0.95, 0.05, 0.05]], dtype=np.float32)
    tiles = rng.integers(0, 3, size=(-(-height // block), -(-width // block)))
    return palette[np.kron(tiles, np.ones((block, block), dtype=int))[:height, :width]]


# --------------------------------------------------------------------------------------------
# TorchSegmenter


class Strided(torch.nn.Module):
    """Average-pools by ``stride`` (ceil mode: sizes need not divide) then the linear classifier;
    returns torchvision's {"out": logits} at the low resolution."""

    def __init__(self, stride: int):
        super().__init__()
        self.stride = stride
        self.classifier = linear_conv()

    def forward(self, x):
        pooled = F.avg_pool2d(x, self.stride, ceil_mode=True)
        return OrderedDict(out=self.classifier(pooled))


def test_torch_segmenter_full_resolution_matches_hand_computed_ids():
    image = np.random.default_rng(1).random((17, 23, 3)).astype(np.float32)
    classes = {0: "dark", 7: "bright", 300: "red"}
    seg = TorchSegmenter(torch.nn.Sequential(linear_conv()), classes, mean=ZERO, std=ONE, device="cpu")
    ids = seg(image)
    assert isinstance(seg, Segmenter)
    assert ids.shape == (17, 23) and ids.dtype == np.int64
    np.testing.assert_array_equal(ids, np.array([0, 7, 300])[expected_channels(image)])
    assert seg.ignore_index is None


def test_torch_segmenter_applies_mean_and_std():
    image = np.random.default_rng(2).random((9, 11, 3)).astype(np.float32)
    mean, std = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)
    seg = TorchSegmenter(linear_conv(), {0: "a", 1: "b", 2: "c"}, device="cpu")  # ImageNet by default
    np.testing.assert_array_equal(seg(image), expected_channels(image, mean, std))


def test_torch_segmenter_resizes_strided_logits_back_to_image_size():
    # 37 x 53 is not divisible by the stride 4: logits are [10, 14], resized back bilinearly
    image = blocky_image(37, 53, block=16)
    seg = TorchSegmenter(Strided(4), {0: "dark", 1: "bright", 2: "red"}, mean=ZERO, std=ONE, device="cpu")
    logits = seg.logits(image)
    assert tuple(logits.shape) == (3, 10, 14)
    ids = seg(image)
    assert ids.shape == (37, 53)
    reference = F.interpolate(logits[None], size=(37, 53), mode="bilinear", align_corners=False)[0].argmax(0)
    np.testing.assert_array_equal(ids, reference.numpy())
    # at the centres of the whole 16 px tiles, the resized prediction is the tile's own class
    truth = expected_channels(image)
    centres = np.ix_([8, 24], [8, 24, 40])
    np.testing.assert_array_equal(ids[centres], truth[centres])
    assert len(np.unique(truth[centres])) > 1


def test_logits_to_ids_in_bands_equals_full_bilinear_resize(monkeypatch):
    import scenelabel.data.segmenters.common as common

    monkeypatch.setattr(common, "_BAND_ELEMENTS", 5 * 61)  # 1 output row per band
    rng = np.random.default_rng(3)
    for (h_in, w_in), (h, w) in [((7, 9), (31, 61)), ((31, 9), (31, 61)), ((7, 61), (31, 61)), ((40, 70), (31, 61))]:
        logits = torch.from_numpy(rng.normal(size=(5, h_in, w_in))).float()
        ids = logits_to_ids(logits, h, w, torch.tensor([3, 1, 4, 10, 20]))
        reference = F.interpolate(logits[None].double(), size=(h, w), mode="bilinear", align_corners=False)[0]
        top2 = reference.topk(2, dim=0).values
        clear = (top2[0] - top2[1] > 1e-4).numpy()
        assert clear.mean() > 0.99
        expected = np.array([3, 1, 4, 10, 20])[reference.argmax(0).numpy()]
        np.testing.assert_array_equal(ids[clear], expected[clear])


def test_torch_segmenter_max_side_shrinks_input_but_returns_full_size():
    seen = []

    class Recorder(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.conv = linear_conv()

        def forward(self, x):
            seen.append(tuple(x.shape))
            return self.conv(x)

    image = blocky_image(60, 100, block=20)
    seg = TorchSegmenter(Recorder(), {0: "dark", 1: "bright", 2: "red"}, mean=ZERO, std=ONE, device="cpu", max_side=25)
    ids = seg(image)
    assert seen == [(1, 3, 15, 25)]
    assert ids.shape == (60, 100)
    truth = expected_channels(image)
    # tile centres (20 px tiles become 5 px at the model) keep their class
    np.testing.assert_array_equal(ids[10::20, 10::20], truth[10::20, 10::20])


def test_torch_segmenter_rejects_wrong_channel_count_and_bad_output():
    seg = TorchSegmenter(linear_conv(3), {0: "a", 1: "b"}, device="cpu")
    with pytest.raises(InputError, match="3 channels but the vocabulary has 2"):
        seg(np.zeros((4, 4, 3), np.float32))

    class NoOut(torch.nn.Module):
        def forward(self, x):
            return {"aux": x}

    with pytest.raises(InputError, match="without 'out'"):
        TorchSegmenter(NoOut(), {0: "a"}, device="cpu")(np.zeros((4, 4, 3), np.float32))
    with pytest.raises(InputError, match=r"\[h, w, 3\]"):
        TorchSegmenter(linear_conv(), {0: "a", 1: "b", 2: "c"}, device="cpu")(np.zeros((4, 4), np.float32))
    with pytest.raises(InputError, match="channel ids"):
        TorchSegmenter(linear_conv(), {0: "a", 1: "b", 2: "c"}, channel_ids=[0, 1, 5], device="cpu")


def test_channel_ids_give_the_class_of_each_channel():
    image = np.random.default_rng(4).random((8, 8, 3)).astype(np.float32)
    classes = {1: "x", 2: "y", 3: "z"}
    seg = TorchSegmenter(linear_conv(), classes, channel_ids=[3, 1, 2], mean=ZERO, std=ONE, device="cpu")
    np.testing.assert_array_equal(seg(image), np.array([3, 1, 2])[expected_channels(image)])


# --------------------------------------------------------------------------------------------
# torchvision (a fake package of the same interface)


class TinyTorchvisionModel(torch.nn.Module):
    """Same interface as torchvision's segmentation models: {"out": logits at input size}, an
    ``aux_classifier`` when built with aux_loss."""

    def __init__(self, num_classes: int, aux_loss: bool):
        super().__init__()
        self.backbone = torch.nn.Identity()
        self.classifier = torch.nn.Conv2d(3, num_classes, 1)
        self.aux_classifier = torch.nn.Conv2d(3, num_classes, 1) if aux_loss else None

    def forward(self, x):
        return OrderedDict(out=self.classifier(self.backbone(x)))


@pytest.fixture
def fake_torchvision(monkeypatch):
    """Insert a fake ``torchvision`` whose models.segmentation builders record their arguments."""
    calls = []

    def builder(arch):
        def build(**kwargs):  # keyword-only, as torchvision's builders
            if arch.startswith("lraspp") and kwargs.get("aux_loss"):
                raise NotImplementedError("This model does not use auxiliary loss")
            calls.append({"arch": arch, **kwargs})
            return TinyTorchvisionModel(kwargs.get("num_classes") or 21, bool(kwargs.get("aux_loss")))

        return build

    package = types.ModuleType("torchvision")
    models = types.ModuleType("torchvision.models")
    segmentation = types.ModuleType("torchvision.models.segmentation")
    for arch in TORCHVISION_ARCHS:
        setattr(segmentation, arch, builder(arch))
    package.models = models
    models.segmentation = segmentation
    monkeypatch.setitem(sys.modules, "torchvision", package)
    monkeypatch.setitem(sys.modules, "torchvision.models", models)
    monkeypatch.setitem(sys.modules, "torchvision.models.segmentation", segmentation)
    return calls


def voc_weights(aux: bool, seed: int = 0, num_classes: int = 21) -> dict[str, torch.Tensor]:
    torch.manual_seed(seed)
    return TinyTorchvisionModel(num_classes, aux).state_dict()


def voc_expected(state: dict[str, torch.Tensor], image: np.ndarray) -> np.ndarray:
    x = (image - np.array([0.485, 0.456, 0.406])) / np.array([0.229, 0.224, 0.225])
    weight = state["classifier.weight"].double().numpy()[:, :, 0, 0]
    return np.argmax(x @ weight.T + state["classifier.bias"].double().numpy(), axis=-1)


def test_torchvision_segmenter_loads_a_weights_file(fake_torchvision, tmp_path):
    state = voc_weights(aux=True)
    path = tmp_path / "my_deeplab.pth"
    torch.save(state, path)
    seg = torchvision_segmenter("deeplabv3_resnet50", path, device="cpu")
    assert fake_torchvision == [{"arch": "deeplabv3_resnet50", "weights": None, "weights_backbone": None,
                                 "num_classes": 21, "aux_loss": True}]
    assert seg.classes == VOC_CLASSES and seg.classes[0] == "background" and seg.classes[20] == "tvmonitor"
    assert seg.colors[15] == (192, 128, 128) and seg.colors[1] == (128, 0, 0)
    image = np.random.default_rng(5).random((13, 19, 3)).astype(np.float32)
    ids = seg(image)
    np.testing.assert_array_equal(ids, voc_expected(state, image))
    assert len(np.unique(ids)) > 2  # random weights and pixels: several VOC classes appear
    for parameter in seg.module.state_dict():
        torch.testing.assert_close(seg.module.state_dict()[parameter], state[parameter])


def test_torchvision_segmenter_checkpoint_layouts(fake_torchvision, tmp_path):
    # torchvision's training references save {"model": state, ...}; DDP prefixes "module."
    state = voc_weights(aux=False, seed=1)
    path = tmp_path / "ckpt.pth"
    torch.save({"model": {f"module.{k}": v for k, v in state.items()}, "epoch": 3}, path)
    seg = torchvision_segmenter("fcn_resnet50", path, device="cpu")
    assert fake_torchvision[-1]["aux_loss"] is False
    image = np.random.default_rng(6).random((5, 7, 3)).astype(np.float32)
    np.testing.assert_array_equal(seg(image), voc_expected(state, image))


def test_torchvision_segmenter_lraspp_gets_no_aux_loss(fake_torchvision, tmp_path):
    path = tmp_path / "lraspp.pth"
    torch.save(voc_weights(aux=False), path)
    torchvision_segmenter("lraspp_mobilenet_v3_large", path, device="cpu")
    assert fake_torchvision[-1] == {"arch": "lraspp_mobilenet_v3_large", "weights": None, "weights_backbone": None,
                                    "num_classes": 21}


def test_torchvision_segmenter_reads_the_torch_hub_cache(fake_torchvision, tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))
    arch = "lraspp_mobilenet_v3_large"
    expected = tmp_path / "torch_home" / "hub" / "checkpoints" / "lraspp_mobilenet_v3_large-d234d4ea.pth"
    assert torchvision_weights_path(arch) == expected
    with pytest.raises(InputError) as info:
        torchvision_segmenter(arch, device="cpu")
    message = str(info.value)
    assert str(expected) in message and info.value.path == expected
    assert "COCO_WITH_VOC_LABELS_V1" in message and "lraspp_mobilenet_v3_large-d234d4ea.pth" in message
    assert "http" not in message  # nothing to download from here: copy the file
    expected.parent.mkdir(parents=True)
    state = voc_weights(aux=False, seed=2)
    torch.save(state, expected)
    seg = torchvision_segmenter(arch, device="cpu")
    image = np.random.default_rng(7).random((6, 9, 3)).astype(np.float32)
    np.testing.assert_array_equal(seg(image), voc_expected(state, image))


def test_torchvision_cache_dir_follows_torch_hub_get_dir(fake_torchvision, tmp_path, monkeypatch):
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hubdir"))
    for arch in TORCHVISION_ARCHS:
        assert torchvision_weights_path(arch) == tmp_path / "hubdir" / "checkpoints" / TORCHVISION_WEIGHT_FILES[arch]
    with pytest.raises(InputError, match="fcn_resnet101_coco-7ecb50ca.pth"):
        torchvision_segmenter("fcn_resnet101")


def test_torchvision_segmenter_errors(fake_torchvision, tmp_path):
    with pytest.raises(InputError, match="unknown torchvision architecture 'resnet50'"):
        torchvision_segmenter("resnet50", tmp_path / "x.pth")
    with pytest.raises(InputError, match="not found") as info:
        torchvision_segmenter("fcn_resnet50", tmp_path / "missing.pth")
    assert info.value.path == tmp_path / "missing.pth"
    garbage = tmp_path / "garbage.pth"
    garbage.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="cannot read the weights") as info:
        torchvision_segmenter("fcn_resnet50", garbage)
    assert info.value.path == garbage
    wrong = tmp_path / "wrong.pth"
    torch.save(voc_weights(aux=False, num_classes=5), wrong)
    with pytest.raises(InputError, match="do not fit torchvision's fcn_resnet50 with num_classes=21"):
        torchvision_segmenter("fcn_resnet50", wrong)
    seg = torchvision_segmenter("fcn_resnet50", wrong, num_classes=5, device="cpu")
    assert seg.classes == {i: f"class_{i}" for i in range(5)}
    seg = torchvision_segmenter("fcn_resnet50", wrong, num_classes=5, classes=dict(enumerate("abcde")), device="cpu")
    assert seg.classes[4] == "e"


def test_torchvision_not_importable_says_how_to_install(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "torchvision", None)  # import torchvision -> ImportError
    with pytest.raises(InputError, match="pip install torchvision"):
        torchvision_segmenter("deeplabv3_resnet50", tmp_path / "w.pth")


def test_voc_palette():
    colors = voc_colors(21)
    assert colors[0] == (0, 0, 0) and colors[2] == (0, 128, 0) and colors[20] == (0, 64, 128)


# --------------------------------------------------------------------------------------------
# ONNX through OpenCV dnn


def make_onnx(path: Path, fixed_size: tuple[int, int] | None = None, stride: int = 1, channels: int = 3) -> Path:
    """A tiny ONNX model: optional AveragePool(stride) then the 1x1 linear classifier (Conv)."""
    h, w = ("h", "w") if fixed_size is None else (fixed_size[1], fixed_size[0])
    inputs = [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, h, w])]
    outputs = [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, channels, "oh", "ow"])]
    nodes, source = [], "image"
    if stride > 1:
        pool = helper.make_node("AveragePool", ["image"], ["pooled"], kernel_shape=[stride] * 2, strides=[stride] * 2)
        nodes.append(pool)
        source = "pooled"
    nodes.append(helper.make_node("Conv", [source, "W", "B"], ["logits"]))
    weights = [
        numpy_helper.from_array(W[:channels].reshape(channels, 3, 1, 1), "W"),
        numpy_helper.from_array(B[:channels], "B"),
    ]
    model = helper.make_model(helper.make_graph(nodes, "tiny", inputs, outputs, initializer=weights),
                              opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def test_onnx_segmenter_matches_hand_computed_ids(tmp_path):
    model = make_onnx(tmp_path / "tiny.onnx")
    seg = OnnxSegmenter(model, {0: "dark", 7: "bright", 300: "red"}, mean=ZERO, std=ONE)
    for shape in [(12, 16), (17, 23)]:  # a dynamic-shape model takes any size
        image = np.random.default_rng(shape[0]).random((*shape, 3)).astype(np.float32)
        ids = seg(image)
        assert ids.shape == shape and ids.dtype == np.int64
        np.testing.assert_array_equal(ids, np.array([0, 7, 300])[expected_channels(image)])


def test_onnx_segmenter_normalisation_and_swap_rb(tmp_path):
    model = make_onnx(tmp_path / "tiny.onnx")
    image = np.random.default_rng(8).random((10, 14, 3)).astype(np.float32)
    mean, std = (0.5, 0.4, 0.3), (0.2, 0.25, 0.3)
    seg = OnnxSegmenter(model, {0: "a", 1: "b", 2: "c"}, mean=mean, std=std)
    np.testing.assert_array_equal(seg(image), expected_channels(image, mean, std))
    # swap_rb: the model sees (B, G, R) of the normalised image
    swapped = OnnxSegmenter(model, {0: "a", 1: "b", 2: "c"}, mean=ZERO, std=ONE, swap_rb=True)
    np.testing.assert_array_equal(swapped(image), expected_channels(image[..., ::-1]))


def test_onnx_segmenter_resizes_strided_logits(tmp_path):
    model = make_onnx(tmp_path / "strided.onnx", stride=4)
    image = blocky_image(37, 53, block=8)  # pooled to [9, 13] (floor), resized back to 37 x 53
    seg = OnnxSegmenter(model, {0: "dark", 1: "bright", 2: "red"}, mean=ZERO, std=ONE)
    logits = seg.logits(image)
    assert logits.shape == (3, 9, 13)
    reference = F.interpolate(torch.from_numpy(logits)[None], size=(37, 53), mode="bilinear", align_corners=False)[0]
    np.testing.assert_array_equal(seg(image), reference.argmax(0).numpy())


def test_onnx_segmenter_fixed_input_size(tmp_path):
    model = make_onnx(tmp_path / "fixed.onnx", fixed_size=(8, 8))
    image = blocky_image(16, 24, block=6)  # 2 x 3 pixel groups of the 8 x 8 input are constant
    image = np.kron(image[::2, ::3], np.ones((2, 3, 1), np.float32))
    seg = OnnxSegmenter(model, {0: "dark", 1: "bright", 2: "red"}, input_size=(8, 8), mean=ZERO, std=ONE)
    logits = seg.logits(image)
    assert logits.shape == (3, 8, 8)
    np.testing.assert_array_equal(logits.argmax(0), expected_channels(image[::2, ::3]))
    reference = F.interpolate(torch.from_numpy(logits)[None], size=(16, 24), mode="bilinear", align_corners=False)[0]
    np.testing.assert_array_equal(seg(image), reference.argmax(0).numpy())


def test_onnx_segmenter_errors(tmp_path):
    with pytest.raises(InputError, match="not found") as info:
        OnnxSegmenter(tmp_path / "none.onnx", {0: "a"})
    assert info.value.path == tmp_path / "none.onnx"
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x00garbage")
    with pytest.raises(InputError, match="cannot read the ONNX model") as info:
        OnnxSegmenter(bad, {0: "a"})
    assert info.value.path == bad
    seg = OnnxSegmenter(make_onnx(tmp_path / "tiny.onnx"), {0: "a", 1: "b"})
    with pytest.raises(InputError, match="3 channels but the vocabulary has 2"):
        seg(np.zeros((4, 4, 3), np.float32))


# --------------------------------------------------------------------------------------------
# spec strings


def write_onnx_spec(tmp_path: Path, preprocess: dict | None = None) -> tuple[Path, Path]:
    model = make_onnx(tmp_path / "tiny.onnx")
    data = {
        "classes": [
            {"id": 300, "name": "red"},
            {"id": 0, "name": "dark"},
            {"id": 7, "name": "bright", "color": [1, 2, 3]},
        ],
        "ignore_index": 255,
    }
    if preprocess is not None:
        data["preprocess"] = preprocess
    classes = tmp_path / "tiny_classes.json"
    classes.write_text(json.dumps(data))
    return model, classes


def test_load_segmenter_onnx_spec_channel_order_is_file_order(tmp_path):
    model, classes = write_onnx_spec(tmp_path, {"mean": [0, 0, 0], "std": [1, 1, 1], "swap_rb": False})
    seg = load_segmenter(f"onnx:{model}:{classes}")
    assert isinstance(seg, OnnxSegmenter)
    assert seg.classes == {300: "red", 0: "dark", 7: "bright"} and seg.ignore_index == 255
    assert seg.channel_ids == [300, 0, 7] and seg.colors == {7: (1, 2, 3)}
    image = np.random.default_rng(9).random((6, 8, 3)).astype(np.float32)
    np.testing.assert_array_equal(seg(image), np.array([300, 0, 7])[expected_channels(image)])


def test_load_segmenter_onnx_spec_preprocess_options(tmp_path):
    model, classes = write_onnx_spec(tmp_path, {"input_size": [8, 6], "swap_rb": True, "max_side": None})
    seg = load_segmenter(f"onnx:{model}:{classes}")
    assert seg.input_size == (8, 6) and seg.swap_rb and seg.max_side is None
    np.testing.assert_allclose(seg.mean, [0.485, 0.456, 0.406], rtol=1e-6)  # ImageNet by default
    assert seg.logits(np.zeros((30, 40, 3), np.float32)).shape == (3, 6, 8)
    model, classes = write_onnx_spec(tmp_path, {"max_side": 10})
    assert load_segmenter(f"onnx:{model}:{classes}").logits(np.zeros((30, 40, 3), np.float32)).shape == (3, 8, 10)


def test_load_segmenter_onnx_spec_errors(tmp_path):
    model, classes = write_onnx_spec(tmp_path, {"mean": [0, 0]})
    with pytest.raises(InputError, match="3 numbers") as info:
        load_segmenter(f"onnx:{model}:{classes}")
    assert info.value.path == classes and info.value.field == "$.preprocess.mean"
    model, classes = write_onnx_spec(tmp_path, {"scale": 2})
    with pytest.raises(InputError, match="unknown keys"):
        load_segmenter(f"onnx:{model}:{classes}")
    with pytest.raises(InputError, match="onnx:MODEL.onnx:CLASSES.json"):
        load_segmenter(f"onnx:{model}")
    with pytest.raises(InputError, match="file not found"):
        load_segmenter(f"onnx:{model}:{tmp_path / 'nope.json'}")


def test_load_segmenter_torchvision_spec(fake_torchvision, tmp_path):
    path = tmp_path / "w.pth"
    torch.save(voc_weights(aux=True), path)
    seg = load_segmenter(f"torchvision:deeplabv3_mobilenet_v3_large:{path}")
    assert isinstance(seg, TorchSegmenter) and seg.classes == VOC_CLASSES
    assert fake_torchvision[-1]["arch"] == "deeplabv3_mobilenet_v3_large"


USER_MODULE = '''
import numpy as np

class Threshold:
    """A user's own segmenter: bright pixels are 'wall' (7), the rest 'floor' (0)."""
    classes = {0: "floor", 7: "wall"}
    ignore_index = None

    def __init__(self, level=0.5):
        self.level = level

    def __call__(self, image):
        return np.where(image.mean(axis=2) > self.level, 7, 0).astype(np.int64)

def make():
    return Threshold(0.25)

instance = Threshold(0.75)
NUMBER = 3

def not_a_segmenter():
    return lambda image: image[..., 0]

def needs_arguments(path):
    return Threshold()
'''


def test_load_segmenter_python_spec(tmp_path, monkeypatch):
    (tmp_path / "my_seg_module.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    image = np.full((2, 2, 3), 0.5, np.float32)
    by_class = load_segmenter("python:my_seg_module:Threshold")
    by_factory = load_segmenter("python:my_seg_module:make")
    by_instance = load_segmenter("python:my_seg_module:instance")
    by_file = load_segmenter(f"python:{tmp_path / 'my_seg_module.py'}:make")
    assert isinstance(by_class, Segmenter)
    assert by_class(image)[0, 0] == 0 and by_factory(image)[0, 0] == 7 and by_instance(image)[0, 0] == 0
    assert by_file(image)[0, 0] == 7 and by_file.classes == {0: "floor", 7: "wall"}
    with pytest.raises(InputError, match="no module named 'no_such_module_xyz'"):
        load_segmenter("python:no_such_module_xyz:make")
    with pytest.raises(InputError, match="has no attribute 'missing'"):
        load_segmenter("python:my_seg_module:missing")
    with pytest.raises(InputError, match="needs a non-empty `classes`"):
        load_segmenter("python:my_seg_module:not_a_segmenter")
    with pytest.raises(InputError, match="called with no arguments"):
        load_segmenter("python:my_seg_module:needs_arguments")
    with pytest.raises(InputError, match="neither a segmenter nor a factory"):
        load_segmenter("python:my_seg_module:NUMBER")
    with pytest.raises(InputError, match="unknown segmenter kind 'caffe'"):
        load_segmenter("caffe:model")
    with pytest.raises(InputError, match="unknown segmenter spec"):
        load_segmenter("deeplab")


# --------------------------------------------------------------------------------------------
# segment_scene


class BlockSegmenter:
    """A user-style segmenter with ids that are not 0..C-1 (and one above 255)."""

    classes = {0: "floor", 7: "wall", 300: "chair"}
    ignore_index = None

    def __call__(self, image):
        return np.array([0, 7, 300])[expected_channels(image)]


def write_images(folder: Path, images: dict[str, np.ndarray]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, array in images.items():
        Image.fromarray(np.round(array * 255).astype(np.uint8)).save(folder / name)


def test_segment_scene_writes_uint16_labels_and_classes(tmp_path):
    rgb = blocky_image(12, 20, block=4, seed=1)
    write_images(tmp_path / "images", {"a.png": rgb, "b.jpg": blocky_image(12, 20, block=5, seed=2)})
    result = segment_scene(tmp_path, BlockSegmenter(), progress=False)
    assert result.label_paths == (tmp_path / "labels" / "a.png", tmp_path / "labels" / "b.png")
    with Image.open(result.label_paths[0]) as png:
        assert png.mode in ("I;16", "I")  # 300 needs 16 bits
    label = read_label(result.label_paths[0], (20, 12))
    np.testing.assert_array_equal(label, np.array([0, 7, 300])[expected_channels(np.round(rgb * 255) / 255)])
    vocabulary = read_classes(result.classes_path)
    assert vocabulary.classes == {0: "floor", 7: "wall", 300: "chair"} and vocabulary.ignore_index is None
    both = np.concatenate([read_label(p, (20, 12)).ravel() for p in result.label_paths])
    assert result.counts == {i: int((both == i).sum()) for i in (0, 7, 300)}
    assert sum(result.counts.values()) == 2 * 12 * 20 and min(result.counts.values()) > 0


def test_segment_scene_grayscale_and_rgba_images(tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    Image.fromarray(np.array([[30, 30, 220, 220]] * 3, np.uint8), mode="L").save(images / "gray.png")
    rgba = np.zeros((3, 4, 4), np.uint8)
    rgba[..., :3] = [240, 10, 10]  # red
    rgba[:, :2, :3] = 200  # bright grey
    rgba[..., 3] = 0  # fully transparent: alpha is dropped, not composited
    Image.fromarray(rgba, mode="RGBA").save(images / "rgba.png")
    segmenter = TorchSegmenter(linear_conv(), {0: "dark", 1: "bright", 2: "red"}, mean=ZERO, std=ONE, device="cpu")
    result = segment_scene(tmp_path, segmenter, progress=False)
    np.testing.assert_array_equal(read_label(result.label_paths[0], (4, 3)), [[0, 0, 1, 1]] * 3)
    np.testing.assert_array_equal(read_label(result.label_paths[1], (4, 3)), [[1, 1, 2, 2]] * 3)
    with Image.open(result.label_paths[0]) as png:
        assert png.mode == "L"  # ids below 256: 8-bit
    assert result.counts == {0: 6, 1: 12, 2: 6}


def test_segment_scene_refuses_existing_labels_unless_overwrite(tmp_path):
    write_images(tmp_path / "images", {"a.png": blocky_image(8, 8, 4)})
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "a.png").write_bytes(b"old")
    with pytest.raises(InputError, match="overwrite") as info:
        segment_scene(tmp_path, BlockSegmenter(), progress=False)
    assert info.value.path == tmp_path / "labels"
    assert (tmp_path / "labels" / "a.png").read_bytes() == b"old" and not (tmp_path / "classes.json").exists()
    segment_scene(tmp_path, BlockSegmenter(), overwrite=True, progress=False)
    assert read_label(tmp_path / "labels" / "a.png", (8, 8)).shape == (8, 8)
    # a classes.json of another vocabulary is refused too; the same vocabulary is fine
    (tmp_path / "labels" / "a.png").unlink()
    segment_scene(tmp_path, BlockSegmenter(), progress=False)
    (tmp_path / "labels" / "a.png").unlink()
    (tmp_path / "classes.json").write_text(json.dumps({"classes": [{"id": 1, "name": "x"}]}))
    with pytest.raises(InputError, match="another vocabulary") as info:
        segment_scene(tmp_path, BlockSegmenter(), progress=False)
    assert info.value.path == tmp_path / "classes.json"
    assert not list((tmp_path / "labels").iterdir())  # nothing written before the refusal


def test_segment_scene_input_errors(tmp_path):
    with pytest.raises(InputError, match="no images/ folder"):
        segment_scene(tmp_path, BlockSegmenter(), progress=False)
    (tmp_path / "images").mkdir()
    with pytest.raises(InputError, match="no PNG or JPEG"):
        segment_scene(tmp_path, BlockSegmenter(), progress=False)
    write_images(tmp_path / "images", {"a.png": blocky_image(4, 4, 2), "a.jpg": blocky_image(4, 4, 2)})
    with pytest.raises(InputError, match="share the label file a.png"):
        segment_scene(tmp_path, BlockSegmenter(), progress=False)
    (tmp_path / "images" / "a.jpg").unlink()

    class Stray(BlockSegmenter):
        def __call__(self, image):
            return np.full(image.shape[:2], 5, np.int64)

    with pytest.raises(InputError, match=r"ids \[5\] that are not in its vocabulary") as info:
        segment_scene(tmp_path, Stray(), progress=False)
    assert info.value.path == tmp_path / "images" / "a.png"

    class WrongShape(BlockSegmenter):
        def __call__(self, image):
            return np.zeros((2, 2), np.int64)

    with pytest.raises(InputError, match=r"returned shape \[2, 2\]"):
        segment_scene(tmp_path, WrongShape(), progress=False)

    class BadVocabulary(BlockSegmenter):
        classes = {0: "floor", 40000: "huge"}

    with pytest.raises(InputError, match="cannot be written as classes.json"):
        segment_scene(tmp_path, BadVocabulary(), progress=False)
    assert not (tmp_path / "classes.json").exists()


def test_segment_scene_then_load_scene(tmp_path):
    from scenelabel import write_toy_scene
    from scenelabel.data.io import load_scene

    scene = write_toy_scene(tmp_path / "scene", n_train=7, n_test=1, width=24, height=18)
    shutil.rmtree(scene / "labels")
    (scene / "classes.json").unlink()

    class WithIgnore(BlockSegmenter):
        ignore_index = 255
        colors = {7: (10, 20, 30)}

        def __call__(self, image):
            ids = super().__call__(image)
            ids[0, 0] = 255
            return ids

    result = segment_scene(scene, WithIgnore(), progress=False)
    assert len(result.label_paths) == 8 and result.counts[255] == 8
    data = json.loads(result.classes_path.read_text())
    assert data == {"classes": [{"id": 0, "name": "floor"}, {"id": 7, "name": "wall", "color": [10, 20, 30]},
                                {"id": 300, "name": "chair"}], "ignore_index": 255}
    loaded = load_scene(scene)
    assert loaded.classes == {0: "floor", 7: "wall", 300: "chair"} and loaded.ignore_index == 255
    first = read_label(result.label_paths[0], (24, 18))
    assert first[0, 0] == 255
    names = sorted(p.name for p in (scene / "labels").iterdir())
    assert names == sorted(p.with_suffix(".png").name for p in (scene / "images").iterdir())
