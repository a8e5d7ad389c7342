"""Sensor depth, masks and applied_transform of transforms.json (nerfstudio's depth_file_path,
depth_unit_scale_factor, mask_path, applied_transform), the Record3D / Polycam / COLMAP layouts
ns-process-data writes, and the phone-like depth writer of the synthetic scenes."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest
from PIL import Image
from test_io_transforms import _opengl_pose  # the same known poses as the transforms.json tests

from scenelabel.data.io import load_scene
from scenelabel.data.io.applied_transform import (
    LEGACY_COLMAP_APPLIED_TRANSFORM,
    check_applied_transform,
    original_frame_aabb,
)
from scenelabel.data.io.depth import (
    DEPTH_AGREEMENT_TOLERANCE,
    WEIGHT_EPS,
    metric_depth_from_raw,
    ray_depth_from_z_depth,
    read_depth_raw,
    resample_depth,
    z_depth_from_ray_depth,
)
from scenelabel.data.io.transforms_json import load_transforms
from scenelabel.data.synthetic import add_phone_depth, write_toy_scene
from scenelabel.data.synthetic.phone_depth import depth_discontinuities
from scenelabel.errors import InputError
from scenelabel.geometry.cameras import OPENGL_TO_OPENCV

FLIP = OPENGL_TO_OPENCV  # OpenGL <-> OpenCV camera axes (its own inverse)
COLMAP_APPLIED = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]]  # ns-process-data's


# ---------------------------------------------------------------------------------------------
# helpers


def make_scene(
    root: Path, n: int = 3, size=(16, 12), edit: Callable[[dict], None] | None = None, suffix: str = ".png", **top
) -> Path:
    """A tiny transforms.json scene: n images of size (w, h), known poses; ``edit`` changes the JSON."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    w, h = size
    frames = []
    for i in range(n):
        pixels = np.random.default_rng(i).integers(0, 256, (h, w, 3), dtype=np.uint8)
        name = f"frame_{i + 1:05d}{suffix}"
        Image.fromarray(pixels).save(root / "images" / name)
        frames.append({"file_path": f"./images/{name}", "transform_matrix": _opengl_pose(i).tolist()})
    data = {"fl_x": 14.0, "fl_y": 13.0, "cx": 7.5, "cy": 6.25, "w": w, "h": h, "frames": frames, **top}
    if edit is not None:
        edit(data)
    (root / "transforms.json").write_text(json.dumps(data))
    return root


def load_quiet(root: Path, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # these scenes load without warnings
        return load_transforms(root, **kwargs)


def write_png16(path: Path, raw: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.asarray(raw, np.uint16)).save(path)


def undistort_loop(u: float, v: float, fx, fy, cx, cy, dist) -> tuple[float, float]:
    """Normalised (x, y) of a distorted pixel: OpenCV's fixed-point inverse, plain float64."""
    k1, k2, p1, p2 = dist
    xd, yd = (u - cx) / fx, (v - cy) / fy
    x, y = xd, yd
    for _ in range(500):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) / radial, (yd - dy) / radial
    return x, y


def ray_depth_loop(z: np.ndarray, fx, fy, cx, cy, dist=(0.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """Reference z-depth -> ray distance, one pixel at a time in float64: t = z * |(x, y, 1)|."""
    h, w = z.shape
    out = np.empty((h, w))
    for r in range(h):
        for c in range(w):
            x, y = undistort_loop(c + 0.5, r + 0.5, fx, fy, cx, cy, dist)
            out[r, c] = z[r, c] * math.sqrt(x * x + y * y + 1.0)
    return out


def resample_loop(depth: np.ndarray, width: int, height: int, tol: float = DEPTH_AGREEMENT_TOLERANCE) -> np.ndarray:
    """Reference resampler, one output pixel at a time in float64 (the rule of resample_depth)."""
    h, w = depth.shape
    out = np.full((height, width), np.nan)
    for r in range(height):
        for c in range(width):
            x = min(max((c + 0.5) * w / width - 0.5, 0.0), w - 1)
            y = min(max((r + 0.5) * h / height - 0.5, 0.0), h - 1)
            x0, y0 = min(int(math.floor(x)), max(w - 2, 0)), min(int(math.floor(y)), max(h - 2, 0))
            taps = []
            for yy, wy in ((y0, 1 - (y - y0)), (min(y0 + 1, h - 1), y - y0)):
                for xx, wx in ((x0, 1 - (x - x0)), (min(x0 + 1, w - 1), x - x0)):
                    if wy * wx > WEIGHT_EPS:
                        taps.append((float(depth[yy, xx]), wy * wx))
            values = [v for v, _ in taps]
            if not all(math.isfinite(v) for v in values):
                continue
            if max(values) - min(values) > tol * min(values):
                continue
            out[r, c] = sum(v * wt for v, wt in taps) / sum(wt for _, wt in taps)
    return out


# ---------------------------------------------------------------------------------------------
# pure functions


def test_ray_depth_from_z_depth_matches_float64_loop_with_distortion() -> None:
    rng = np.random.default_rng(0)
    z = rng.uniform(0.5, 4.0, (9, 13))
    intr = (12.0, 11.0, 6.1, 4.7)
    for dist in ((0.0, 0.0, 0.0, 0.0), (-0.12, 0.03, 0.002, -0.001)):
        got = ray_depth_from_z_depth(z, *intr, np.array(dist))
        np.testing.assert_allclose(got, ray_depth_loop(z, *intr, dist), rtol=2e-6)
        back = z_depth_from_ray_depth(got, *intr, np.array(dist))
        np.testing.assert_allclose(back, z, rtol=2e-6)
    assert np.all(ray_depth_from_z_depth(z, *intr) >= z.astype(np.float32))  # the ray is never shorter
    z[2, 3] = np.nan
    assert np.isnan(ray_depth_from_z_depth(z, *intr)[2, 3])


@pytest.mark.parametrize("size", [(20, 16), (10, 7), (3, 2), (5, 4), (13, 9), (1, 1)])
def test_resample_depth_matches_float64_loop(size) -> None:
    rng = np.random.default_rng(1)
    depth = rng.uniform(2.0, 2.3, (4, 5))  # spreads around the tolerance: some blends pass, some not
    depth[1, 2] = np.nan
    depth[3, 0] = 6.0  # an edge
    got = resample_depth(depth, *size)
    want = resample_loop(depth, *size)
    assert got.shape == (size[1], size[0]) and got.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got[~np.isnan(got)], want[~np.isnan(want)], rtol=1e-6)
    assert np.isfinite(got).any() or size == (1, 1)


def test_resample_depth_same_size_is_identity_and_exact_alignment_ignores_neighbours() -> None:
    depth = np.array([[1.0, np.nan, 3.0], [4.0, 5.0, 60.0]], np.float32)
    np.testing.assert_array_equal(resample_depth(depth, 3, 2), depth)
    # 3x downsampling: the single output centre is the middle sample's centre, which alone counts
    odd = np.array([[2.0, np.nan, 2.0], [2.0, 2.0, 9.0], [2.0, 2.0, 2.0]])
    assert resample_depth(odd, 1, 1)[0, 0] == 2.0


def test_resample_depth_never_blends_across_an_edge_and_keeps_holes() -> None:
    depth = np.full((6, 8), 2.0)
    depth[:, 4:] = 3.0  # a step: 50 % apart
    depth[2, 1] = np.nan
    up = resample_depth(depth, 32, 24)
    finite = up[np.isfinite(up)]
    assert np.all((np.abs(finite - 2.0) < 1e-6) | (np.abs(finite - 3.0) < 1e-6))
    assert np.all(np.isnan(up[:, 14:18]))  # the 4 colour columns between the edge's sample centres
    # the colour pixels whose four taps include sample (2, 1): x in (0, 2), y in (1, 3) -> cols 2..9, rows 6..13
    assert np.all(np.isnan(up[6:14, 2:10]))
    assert np.all(np.isfinite(up[6:14, 10:14])) and np.all(np.isfinite(up[14:, 2:10]))


def test_resample_depth_is_exact_on_a_linear_ramp() -> None:
    cols = np.arange(6, dtype=np.float64)
    depth = np.tile(2.0 + 0.01 * cols, (3, 1))  # neighbours 0.5 % apart: always blended
    up = resample_depth(depth, 24, 12)
    x = np.clip((np.arange(24) + 0.5) / 4 - 0.5, 0, 5)
    np.testing.assert_allclose(up, np.tile(2.0 + 0.01 * x, (12, 1)), rtol=1e-6)


def test_metric_depth_from_raw_holes() -> None:
    raw = np.array([[1000.0, 0.0, -5.0], [np.nan, np.inf, 2500.0]])
    got = metric_depth_from_raw(raw, 1e-3)
    np.testing.assert_allclose(got[0, 0], 1.0)
    np.testing.assert_allclose(got[1, 2], 2.5)
    assert np.isnan(got[0, 1:]).all() and np.isnan(got[1, :2]).all()


# ---------------------------------------------------------------------------------------------
# depth formats and scale factors through the loader


def _expected_ray(z: np.ndarray, scene, i: int) -> np.ndarray:
    c = scene.cameras
    return ray_depth_loop(z, c.fx[i], c.fy[i], c.cx[i], c.cy[i], tuple(c.distortion[i]))


def test_depth_formats_and_scale_factors(tmp_path: Path) -> None:
    w, h = 16, 12
    rng = np.random.default_rng(2)
    z_true = rng.uniform(1.0, 3.0, (h, w))  # metres, millimetre-exact below
    z_true = np.round(z_true * 1000) / 1000

    def edit(data):
        f = data["frames"]
        f[0]["depth_file_path"] = "depth/a.png"  # 16-bit millimetres, default factor 1e-3
        f[1]["depth_file_path"] = "depth/b.npy"  # float metres: per-frame factor 1 beats the global
        f[1]["depth_unit_scale_factor"] = 1.0
        f[2]["depth_file_path"] = "depth/c.tiff"  # float centimetres, factor 0.01
        f[2]["depth_unit_scale_factor"] = 0.01
        f[3]["depth_file_path"] = "depth/d.png"  # 8-bit decimetres
        f[3]["depth_unit_scale_factor"] = 0.1

    root = tmp_path / "s"
    (root / "depth").mkdir(parents=True)
    write_png16(root / "depth" / "a.png", np.round(z_true * 1000))
    np.save(root / "depth" / "b.npy", z_true.astype(np.float32))
    assert cv2.imwrite(str(root / "depth" / "c.tiff"), (z_true * 100).astype(np.float32))
    Image.fromarray(np.round(z_true * 10).astype(np.uint8)).save(root / "depth" / "d.png")
    make_scene(root, n=5, size=(w, h), edit=edit, depth_unit_scale_factor=0.001)
    scene = load_quiet(root)
    assert len(scene.sensor_depths) == 5 and scene.sensor_depths[4] is None
    assert scene.depths == [None] * 5  # the scoring ground truth is depth_path only
    for i, z in enumerate([z_true, z_true, z_true, np.round(z_true * 10) / 10]):
        got = scene.sensor_depths[i]
        assert got.dtype == np.float32 and got.shape == (h, w)
        np.testing.assert_allclose(got, _expected_ray(z, scene, i), rtol=1e-6)
    # a known pixel by hand: (row 5, col 9), centre (9.5, 5.5)
    x, y = (9.5 - 7.5) / 14.0, (5.5 - 6.25) / 13.0
    assert scene.sensor_depths[0][5, 9] == pytest.approx(z_true[5, 9] * math.sqrt(x * x + y * y + 1), rel=1e-6)
    info = scene.info
    assert info["sensor_depth_views"] == 4 and info["masked_views"] == 0
    assert info["depth_unit_scale_factors"] == [0.001, 0.01, 0.1, 1.0]
    assert scene.masks is None


def test_npy_depth_is_scaled_like_nerfstudio_and_metres_warn(tmp_path: Path) -> None:
    """nerfstudio multiplies .npy by depth_unit_scale_factor too (default 1e-3): float millimetres
    load silently; float metres left at the default come out 1000x small, which warns."""
    root = tmp_path / "s"
    (root / "depth").mkdir(parents=True)
    np.save(root / "depth" / "mm.npy", np.full((12, 16), 2500.0))
    np.save(root / "depth" / "m.npy", np.full((12, 16), 2.5))

    def edit(data):
        data["frames"][0]["depth_file_path"] = "depth/mm.npy"

    scene = load_quiet(make_scene(root, edit=edit))
    assert scene.sensor_depths[0][6, 7] == pytest.approx(2.5 * math.sqrt(1 + (0.25 / 13) ** 2), rel=1e-6)

    def edit_metres(data):
        data["frames"][0]["depth_file_path"] = "depth/m.npy"

    with pytest.warns(UserWarning, match="depth_unit_scale_factor"):
        load_transforms(make_scene(root, edit=edit_metres))


def test_depth_holes_stay_nan(tmp_path: Path) -> None:
    root = tmp_path / "s"
    raw = np.full((12, 16), 2.0)
    raw[0, 0], raw[1, 1], raw[2, 2], raw[3, 3] = 0.0, -1.0, np.nan, np.inf
    (root / "depth").mkdir(parents=True)
    np.save(root / "depth" / "d.npy", raw)
    png = np.full((12, 16), 2000, np.uint16)
    png[5, 5] = 0
    write_png16(root / "depth" / "d.png", png)

    def edit(data):
        data["frames"][0].update(depth_file_path="depth/d.npy", depth_unit_scale_factor=1.0)
        data["frames"][1].update(depth_file_path="depth/d.png")

    scene = load_quiet(make_scene(root, edit=edit))
    npy, png_depth = scene.sensor_depths[0], scene.sensor_depths[1]
    assert np.isnan([npy[0, 0], npy[1, 1], npy[2, 2], npy[3, 3]]).all()
    assert np.isfinite(npy).sum() == 12 * 16 - 4
    assert np.isnan(png_depth[5, 5]) and np.isfinite(png_depth).sum() == 12 * 16 - 1


def write_exr(path: Path, channels: dict[str, np.ndarray]) -> None:
    import OpenEXR

    path.parent.mkdir(parents=True, exist_ok=True)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, channels) as exr:
        exr.write(str(path))


def test_exr_depth_channels(tmp_path: Path) -> None:
    """EXR is read with the OpenEXR bindings: a Z (or depth, or Y) channel, a single channel of
    any name, half floats widened, a grey image stored as equal R, G, B; else a clear error."""
    z = np.random.default_rng(3).uniform(0.5, 3.0, (3, 4)).astype(np.float32)
    write_exr(tmp_path / "z.exr", {"Z": z, "R": z + 1.0})
    np.testing.assert_array_equal(read_depth_raw(tmp_path / "z.exr"), z)
    write_exr(tmp_path / "one.exr", {"A": z})
    np.testing.assert_array_equal(read_depth_raw(tmp_path / "one.exr"), z)
    half = z.astype(np.float16)
    write_exr(tmp_path / "half.exr", {"Y": half})
    out = read_depth_raw(tmp_path / "half.exr")
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, half.astype(np.float32))
    write_exr(tmp_path / "grey.exr", {"RGB": np.stack([z, z, z], -1)})
    np.testing.assert_array_equal(read_depth_raw(tmp_path / "grey.exr"), z)
    write_exr(tmp_path / "colour.exr", {"RGB": np.stack([z, z + 1, z], -1)})
    with pytest.raises(InputError, match="one named Z, depth, Y; this one has B, G, R"):
        read_depth_raw(tmp_path / "colour.exr")
    (tmp_path / "bad.exr").write_bytes(b"v/1\x01" + bytes(60))  # an EXR magic number, then nothing
    with pytest.raises(InputError, match="cannot read the EXR depth"):
        read_depth_raw(tmp_path / "bad.exr")


def test_exr_depth_in_a_scene(tmp_path: Path) -> None:
    """A float EXR in metres (``depth_unit_scale_factor`` 1.0) loads as the same depth as a .npy."""
    root = tmp_path / "s"
    z = np.full((12, 16), 2.5, np.float32)
    z[3, 4] = 0.0  # a hole
    write_exr(root / "depth" / "d.exr", {"Z": z})
    np.save(root / "depth" / "d.npy", z)

    def edit(data):
        data["frames"][0].update(depth_file_path="depth/d.exr", depth_unit_scale_factor=1.0)
        data["frames"][1].update(depth_file_path="depth/d.npy", depth_unit_scale_factor=1.0)

    scene = load_quiet(make_scene(root, edit=edit))
    assert np.isnan(scene.sensor_depths[0][3, 4])
    np.testing.assert_array_equal(np.isnan(scene.sensor_depths[0]), np.isnan(scene.sensor_depths[1]))
    assert scene.sensor_depths[0][6, 7] == pytest.approx(float(_expected_ray(z, scene, 0)[6, 7]), rel=1e-6)


def test_low_resolution_depth_aligned_by_intrinsics(tmp_path: Path) -> None:
    """A 4x3 depth for a 16x12 image (a phone's LiDAR): sample (i, j)'s centre is colour pixel
    coordinate (4 (j + 0.5), 4 (i + 0.5)); a hole removes exactly the colour pixels it is a tap of."""
    root = tmp_path / "s"
    raw = np.full((3, 4), 2000, np.uint16)
    raw[1, 1] = 0
    write_png16(root / "depth" / "low.png", raw)
    ramp = np.tile(np.array([2000, 2010, 2020, 2030], np.uint16), (3, 1))
    write_png16(root / "depth" / "ramp.png", ramp)

    def edit(data):
        data["frames"][0]["depth_file_path"] = "depth/low.png"
        data["frames"][1]["depth_file_path"] = "depth/ramp.png"

    scene = load_quiet(make_scene(root, edit=edit))
    got = scene.sensor_depths[0]
    z = np.full((12, 16), 2.0)
    hole = np.zeros((12, 16), bool)
    hole[2:10, 2:10] = True  # x = (c + 0.5) / 4 - 0.5 in (0, 2) and y in (0, 2)
    z[hole] = np.nan
    want = _expected_ray(z, scene, 0)
    np.testing.assert_array_equal(np.isnan(got), hole)
    np.testing.assert_allclose(got[~hole], want[~hole], rtol=1e-6)
    x = np.clip((np.arange(16) + 0.5) / 4 - 0.5, 0, 3)
    z_ramp = np.tile(2.0 + 0.01 * x, (12, 1))
    np.testing.assert_allclose(scene.sensor_depths[1], _expected_ray(z_ramp, scene, 1), rtol=1e-6)


def test_depth_follows_downscale_and_the_frame_intrinsics(tmp_path: Path) -> None:
    root = tmp_path / "s"
    write_png16(root / "depth" / "full.png", np.full((12, 16), 1500))

    def edit(data):
        data["frames"][1].update(depth_file_path="depth/full.png", fl_x=9.0, cx=5.0, k1=-0.05)

    scene = load_quiet(make_scene(root, edit=edit), downscale=2)
    got = scene.sensor_depths[1]
    assert got.shape == (6, 8)
    assert scene.cameras.fx[1] == 4.5 and scene.cameras.cx[1] == 2.5
    np.testing.assert_allclose(got, _expected_ray(np.full((6, 8), 1.5), scene, 1), rtol=1e-6)


# ---------------------------------------------------------------------------------------------
# masks


def test_masks_full_and_low_resolution(tmp_path: Path) -> None:
    root = tmp_path / "s"
    (root / "masks").mkdir(parents=True)
    full = np.full((12, 16), 255, np.uint8)
    full[:, :5] = 0
    Image.fromarray(full).save(root / "masks" / "full.png")
    low = np.array([[0, 1], [7, 0]], np.uint8)  # any non-zero value means "use"
    Image.fromarray(low).save(root / "masks" / "low.png")

    def edit(data):
        data["frames"][0]["mask_path"] = "masks/full.png"
        data["frames"][2]["mask_path"] = "masks/low.png"

    scene = load_quiet(make_scene(root, edit=edit))
    assert scene.masks[1] is None and scene.sensor_depths is None
    np.testing.assert_array_equal(scene.masks[0], full != 0)
    assert scene.masks[0].dtype == bool
    want = np.zeros((12, 16), bool)
    want[:6, 8:] = True
    want[6:, :8] = True
    np.testing.assert_array_equal(scene.masks[2], want)
    assert scene.info["masked_views"] == 2
    half = load_quiet(root, downscale=2)
    np.testing.assert_array_equal(half.masks[0], (full != 0)[1::2, 1::2])  # nearest: the pixel holding the centre


def test_no_masks_no_depth_fields_are_none(tmp_path: Path) -> None:
    scene = load_quiet(make_scene(tmp_path / "s"))
    assert scene.masks is None and scene.sensor_depths is None
    assert scene.info["applied_transform"] is None and scene.info["world_frame"] == "transforms"


# ---------------------------------------------------------------------------------------------
# applied_transform


def test_applied_transform_recorded_and_original_frame(tmp_path: Path) -> None:
    """ns-process-data (COLMAP): transform_matrix = A @ (COLMAP c2w in OpenGL axes); scenelabel keeps
    the transform_matrix frame and can go back: A^-1 @ c2w is COLMAP's camera-to-world."""
    applied = np.vstack([COLMAP_APPLIED, [0, 0, 0, 1]])
    colmap_c2w = [_opengl_pose(i + 3) @ FLIP for i in range(3)]  # OpenCV axes, COLMAP's world

    def edit(data):
        for i, frame in enumerate(data["frames"]):
            frame["transform_matrix"] = (applied @ colmap_c2w[i] @ FLIP).tolist()

    root = make_scene(tmp_path / "s", edit=edit, applied_transform=COLMAP_APPLIED, aabb=[[-1, -2, -3], [1, 2, 3]])
    default = load_quiet(root)
    np.testing.assert_allclose(default.info["applied_transform"], applied)
    assert default.info["applied_transform_source"] == "file"
    for i in range(3):
        np.testing.assert_allclose(default.cameras.c2w[i], applied @ colmap_c2w[i], atol=1e-12)
    original = load_quiet(root, world_frame="original")
    assert original.info["world_frame"] == "original"
    for i in range(3):
        np.testing.assert_allclose(original.cameras.c2w[i], colmap_c2w[i], atol=1e-12)
    # the box: COLMAP y = -z_ns, z = y_ns
    np.testing.assert_allclose(original.aabb, [[-1, -3, -2], [1, 3, 2]], atol=1e-12)
    np.testing.assert_allclose(original_frame_aabb(np.array([[-1, -2, -3], [1, 2, 3]]), np.eye(4)), [[-1, -2, -3], [1, 2, 3]])


def test_applied_transform_legacy_colmap_default(tmp_path: Path) -> None:
    root = make_scene(tmp_path / "s")
    (root / "colmap" / "sparse" / "0").mkdir(parents=True)
    scene = load_quiet(root)
    np.testing.assert_allclose(np.asarray(scene.info["applied_transform"])[:3], LEGACY_COLMAP_APPLIED_TRANSFORM)
    assert scene.info["applied_transform_source"] == "nerfstudio legacy COLMAP default"


@pytest.mark.parametrize(
    "value, match",
    [
        ([[1, 0, 0, 0], [0, 1, 0, 0]], "4x4 or 3x4"),
        ([[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0]], "rigid"),
        ([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], "rigid"),  # a mirror
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "bottom row"),
        ([[1, 0, 0, float("nan")], [0, 1, 0, 0], [0, 0, 1, 0]], "non-finite"),
        ("identity", "matrix"),
    ],
)
def test_bad_applied_transform(value, match) -> None:
    with pytest.raises(InputError, match=match):
        check_applied_transform(value, Path("transforms.json"))


def test_bad_applied_transform_in_file_and_bad_world_frame(tmp_path: Path) -> None:
    root = make_scene(tmp_path / "s", applied_transform=[[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0]])
    with pytest.raises(InputError, match="applied_transform") as err:
        load_transforms(root)
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="world_frame"):
        load_transforms(make_scene(tmp_path / "t"), world_frame="colmap")


# ---------------------------------------------------------------------------------------------
# errors


def _frame0(**keys):
    def edit(data):
        data["frames"][0].update(keys)

    return edit


@pytest.mark.parametrize(
    "setup, match",
    [
        (lambda root: _frame0(depth_file_path="depth/none.png"), "depth file 'depth/none.png' not found"),
        (lambda root: (root / "depth" / "bad.png").write_bytes(b"\x89PNG garbage") and _frame0(depth_file_path="depth/bad.png"),
         "cannot read the depth image"),
        (lambda root: Image.fromarray(np.zeros((12, 16, 3), np.uint8)).save(root / "depth" / "rgb.png")
         or _frame0(depth_file_path="depth/rgb.png"), "one channel, got 3"),
        (lambda root: write_png16(root / "depth" / "sq.png", np.ones((10, 10)))
         or _frame0(depth_file_path="depth/sq.png"), "aspect"),
        (lambda root: np.save(root / "depth" / "x.npy", np.ones((12, 16)))
         or _frame0(depth_file_path="depth/x.npy", depth_unit_scale_factor=0), "depth_unit_scale_factor must be a positive"),
        (lambda root: (root / "depth" / "x.jpg").write_bytes(b"")
         or _frame0(depth_file_path="depth/x.jpg"), "depth files must be"),
        (lambda root: _frame0(mask_path="masks/none.png"), "mask file 'masks/none.png' not found"),
        (lambda root: Image.fromarray(np.zeros((5, 5), np.uint8)).save(root / "masks" / "sq.png")
         or _frame0(mask_path="masks/sq.png"), "aspect"),
        (lambda root: Image.fromarray(np.zeros((12, 16, 3), np.uint8)).save(root / "masks" / "rgb.png")
         or _frame0(mask_path="masks/rgb.png"), "single-channel"),
    ],
)
def test_depth_and_mask_errors_are_one_line(tmp_path: Path, setup, match) -> None:
    root = tmp_path / "s"
    (root / "depth").mkdir(parents=True)
    (root / "masks").mkdir()
    edit = setup(root)
    make_scene(root, edit=edit)
    with pytest.raises(InputError, match=match) as err:
        load_transforms(root)
    assert "\n" not in str(err.value)


def test_non_positive_global_scale_factor(tmp_path: Path) -> None:
    root = make_scene(tmp_path / "s", depth_unit_scale_factor=-1.0)
    with pytest.raises(InputError, match=r"\$\.depth_unit_scale_factor"):
        load_transforms(root)


# ---------------------------------------------------------------------------------------------
# the layouts ns-process-data writes


def test_polycam_layout(tmp_path: Path) -> None:
    """ns-process-data polycam --use-depth: images/ and depth/ frame_%05d, per-frame intrinsics,
    camera_model OPENCV, orientation_override "none", depth 16-bit PNG millimetres upscaled to the
    image size, no applied_transform."""
    root = tmp_path / "polycam"
    sizes = [(16, 12), (16, 12), (20, 15)]
    frames = []
    z_mm = []
    for i, (w, h) in enumerate(sizes):
        (root / "images").mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.full((h, w, 3), 90 + i, np.uint8)).save(root / "images" / f"frame_{i + 1:05d}.jpg")
        z = 1000 + 100 * i + np.arange(w)[None, :] * 3 + np.zeros((h, 1), int)  # millimetres, a gentle ramp
        write_png16(root / "depth" / f"frame_{i + 1:05d}.png", z)
        z_mm.append(z)
        frames.append({
            "fl_x": 15.0 + i, "fl_y": 15.5 + i, "cx": w / 2 - 0.3 * i, "cy": h / 2 + 0.2 * i, "w": w, "h": h,
            "file_path": f"./images/frame_{i + 1:05d}.jpg",
            "depth_file_path": f"./depth/frame_{i + 1:05d}.png",
            "transform_matrix": _opengl_pose(i).tolist(),
        })
    (root / "transforms.json").write_text(json.dumps({"camera_model": "OPENCV", "orientation_override": "none",
                                                      "frames": frames}, indent=4))
    scene = load_scene(root)
    np.testing.assert_array_equal(scene.cameras.fx, [15.0, 16.0, 17.0])
    np.testing.assert_array_equal(scene.cameras.width, [16, 16, 20])
    np.testing.assert_allclose(scene.cameras.cx, [8.0, 7.7, 9.4])
    for i in range(3):
        np.testing.assert_allclose(scene.cameras.c2w[i], _opengl_pose(i) @ FLIP, atol=1e-12)
        np.testing.assert_allclose(scene.sensor_depths[i], _expected_ray(z_mm[i] / 1000.0, scene, i), rtol=1e-6)
    # frame 3, pixel (row 7, col 4): z = 1.2 m + 12 mm, by hand
    x, y = (4.5 - 9.4) / 17.0, (7.5 - 7.9) / 17.5
    assert scene.sensor_depths[2][7, 4] == pytest.approx(1.212 * math.sqrt(x * x + y * y + 1), rel=1e-6)
    assert scene.info["applied_transform"] is None and scene.info["image_folder"] == "images"


def test_record3d_layout_with_low_resolution_depth_and_masks(tmp_path: Path) -> None:
    """ns-process-data record3d: images/frame_%05d.jpg, one global fl_x = fl_y, cx = w / 2, cy = h / 2,
    camera_model OPENCV, no depth; Record3D's own 256x192-style depth (metres, z-depth; here as .npy
    with depth_unit_scale_factor 1) and masks added per frame at 1/4 resolution."""
    root = tmp_path / "record3d"
    w, h = 24, 32  # portrait, as an iPhone records
    (root / "depth").mkdir(parents=True)
    (root / "masks").mkdir()

    def edit(data):
        for i, frame in enumerate(data["frames"]):
            z = np.full((8, 6), 1.25 + 0.5 * i, np.float32)
            z[0, 0] = 0.0  # no return
            np.save(root / "depth" / f"{i}.npy", z)
            conf = np.full((8, 6), 2, np.uint8)
            conf[7, :] = 0  # low confidence: ignore
            Image.fromarray(conf).save(root / "masks" / f"{i}.png")
            frame.update(depth_file_path=f"depth/{i}.npy", mask_path=f"masks/{i}.png")

    make_scene(root, n=2, size=(w, h), edit=edit, suffix=".jpg", fl_x=20.0, fl_y=20.0, cx=w / 2, cy=h / 2,
               camera_model="OPENCV", depth_unit_scale_factor=1.0)
    scene = load_scene(root)
    assert scene.cameras.fx.tolist() == [20.0, 20.0] and scene.cameras.cx.tolist() == [12.0, 12.0]
    for i in range(2):
        depth = scene.sensor_depths[i]
        assert depth.shape == (h, w)
        assert np.isnan(depth[:6, :6]).all()  # colour pixels with sample (0, 0) among their taps
        ok = np.isfinite(depth)
        assert ok.sum() == h * w - 36
        np.testing.assert_allclose(depth[ok], _expected_ray(np.full((h, w), 1.25 + 0.5 * i), scene, i)[ok], rtol=1e-6)
        want = np.ones((h, w), bool)
        want[28:, :] = False  # the last depth row covers the last 4 colour rows
        np.testing.assert_array_equal(scene.masks[i], want)


def test_colmap_layout_with_sparse_sfm_depth_and_applied_transform(tmp_path: Path) -> None:
    """ns-process-data images --use-sfm-depth: depth/ 16-bit PNGs of millimetres, zero but at the SfM
    points' pixels, and the applied_transform of the COLMAP conversion."""
    root = tmp_path / "colmap"
    sparse = np.zeros((12, 16), np.uint16)
    sparse[3, 4], sparse[9, 12] = 1834, 2760
    write_png16(root / "depth" / "frame_00001.png", sparse)

    def edit(data):
        data["frames"][0]["depth_file_path"] = "depth/frame_00001.png"
        data["frames"][0]["colmap_im_id"] = 1

    scene = load_scene(make_scene(root, edit=edit, camera_model="OPENCV", applied_transform=COLMAP_APPLIED))
    depth = scene.sensor_depths[0]
    assert np.isfinite(depth).sum() == 2
    want = _expected_ray(sparse / 1000.0, scene, 0)
    assert depth[3, 4] == pytest.approx(want[3, 4], rel=1e-6) and depth[9, 12] == pytest.approx(want[9, 12], rel=1e-6)
    assert scene.info["applied_transform_source"] == "file"


# ---------------------------------------------------------------------------------------------
# phone-like depth of the synthetic scenes


def _tiny_synthetic(root: Path, truth: np.ndarray, image: np.ndarray) -> Path:
    """A scene folder as scenelabel.data.synthetic writes it, with a given true ray depth."""
    h, w = truth.shape
    for sub in ("images", "depths"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    frames = []
    for i in range(2):
        Image.fromarray(image).save(root / "images" / f"{i:03d}.png")
        np.save(root / "depths" / f"{i:03d}.npy", truth.astype(np.float32))
        frames.append({"file_path": f"images/{i:03d}.png", "depth_path": f"depths/{i:03d}.npy",
                       "transform_matrix": _opengl_pose(i).tolist()})
    data = {"camera_model": "PINHOLE", "fl_x": 20.0, "fl_y": 20.0, "cx": w / 2, "cy": h / 2, "w": w, "h": h,
            "frames": frames}
    (root / "transforms.json").write_text(json.dumps(data))
    return root


def test_phone_depth_holes_where_a_phone_has_none(tmp_path: Path) -> None:
    w, h = 16, 12
    z = np.full((h, w), 2.0)
    z[:, 10:] = 3.0  # a step inside depth column 2 (colour columns 8..11)
    z[8:, :4] = 6.0  # beyond max_range, depth pixel (2, 0)
    truth = ray_depth_from_z_depth(z, 20.0, 20.0, w / 2, h / 2)  # the ray distances of these z-depths
    truth[0, 15] = 0.0  # no surface in one colour pixel of depth pixel (0, 3)
    image = np.full((h, w, 3), 200, np.uint8)
    image[4:8, 4:8] = 5  # dark: depth pixel (1, 1)
    root = _tiny_synthetic(tmp_path / "s", truth, image)
    add_phone_depth(root, scale=4, noise=0.0, dropout=0.0)
    raw = np.array(Image.open(root / "depth" / "000.png"))
    assert raw.dtype == np.uint16 and raw.shape == (3, 4)
    # (0, 2), (1, 2), (2, 2): the 2 | 3 m step at colour column 10; (0, 3): a colour pixel without surface;
    # (1, 1): dark; (2, 0): beyond 5 m; (1, 0) and (2, 1): beside the 6 m block (colour row 7, column 4)
    want = np.array([[2000, 2000, 0, 0], [0, 0, 0, 3000], [0, 0, 0, 3000]])
    np.testing.assert_array_equal(raw, want)
    add_phone_depth(root, scale=4, noise=0.0, dropout=0.0, max_range=None, dark_threshold=0.0, edge_threshold=10.0)
    raw = np.array(Image.open(root / "depth" / "000.png"))  # no edge, range or dark holes: the rest stay
    np.testing.assert_array_equal(raw, [[2000, 2000, 2500, 0], [2000, 2000, 2500, 3000], [6000, 2000, 2500, 3000]])
    add_phone_depth(root, scale=4, noise=0.0, dropout=0.0)
    data = json.loads((root / "transforms.json").read_text())
    assert data["depth_unit_scale_factor"] == 0.001 and data["phone_depth"]["scale"] == 4
    assert data["frames"][1]["depth_file_path"] == "depth/001.png"
    assert data["frames"][1]["depth_path"] == "depths/001.npy"  # scoring truth untouched
    scene = load_quiet(root)
    np.testing.assert_array_equal(scene.depths[0], truth.astype(np.float32))
    finite = np.isfinite(scene.sensor_depths[0])
    np.testing.assert_allclose(scene.sensor_depths[0][finite], truth[finite], rtol=1e-6)


def test_depth_discontinuities_flag_steps_not_slanted_planes() -> None:
    u = np.arange(40) + 0.5
    z_plane = 1.0 / (0.3 + 0.004 * u)  # a slanted plane: 1 / z affine in the pixel column
    z = np.tile(z_plane, (5, 1))
    assert not depth_discontinuities(z, 0.05).any()
    z[:, 20:] *= 1.3  # a step
    z[2, 5] = np.nan  # no surface
    edge = depth_discontinuities(z, 0.05)
    assert edge[:, 19].all() and edge[:, 20].all()
    assert edge[2, 4] and edge[2, 6] and edge[1, 5] and edge[3, 5] and not edge[2, 5]
    assert edge.sum() == 10 + 4


def test_phone_depth_reproducible_noise_level_and_holes(tmp_path: Path) -> None:
    noise = 0.015
    root = write_toy_scene(tmp_path / "toy", n_train=7, n_test=1, width=96, height=72)
    add_phone_depth(root, noise=noise, seed=5)
    first = [p.read_bytes() for p in sorted((root / "depth").glob("*.png"))]
    add_phone_depth(root, noise=noise, seed=5)
    assert [p.read_bytes() for p in sorted((root / "depth").glob("*.png"))] == first
    add_phone_depth(root, noise=noise, seed=6)
    assert [p.read_bytes() for p in sorted((root / "depth").glob("*.png"))] != first
    add_phone_depth(root, noise=noise, seed=5)

    scene = load_quiet(root)
    rel, holes, rel_lowres = [], [], []
    for i in range(len(scene)):
        truth = scene.depths[i].astype(np.float64)
        surface = truth > 0
        sensor = scene.sensor_depths[i]
        ok = surface & np.isfinite(sensor)
        rel.append(np.abs(sensor[ok] / truth[ok] - 1))
        holes.append(np.mean(~np.isfinite(sensor[surface])))
        assert not np.isfinite(sensor[~surface]).any()  # no depth where nothing is
        # at the depth's own resolution, against the median true z of each 4x4 block
        c = scene.cameras
        z = z_depth_from_ray_depth(np.where(surface, truth, np.nan), c.fx[i], c.fy[i], c.cx[i], c.cy[i])
        block = np.median(z.reshape(18, 4, 24, 4), axis=(1, 3))
        raw = read_depth_raw(root / "depth" / f"{scene.names[i]}.png").astype(np.float64) / 1000
        valid = raw > 0
        assert np.isfinite(block[valid]).all()
        rel_lowres.append(np.abs(raw[valid] / block[valid] - 1))
    lowres = np.median(np.concatenate(rel_lowres))
    assert abs(lowres / (0.6745 * noise) - 1) < 0.15  # the median |N(0, noise)|
    colour = np.median(np.concatenate(rel))
    assert 0.3 * noise < colour < noise  # bilinear blends of four samples average some noise away
    assert 0.05 < np.mean(holes) < 0.7
    assert np.concatenate(rel).max() < DEPTH_AGREEMENT_TOLERANCE + 5 * noise


def test_sparse_depth_lost_by_downscale_warns(tmp_path: Path) -> None:
    """Isolated SfM samples survive at full resolution (each pixel takes its own sample) but not a
    downscale (a blend needs every tap valid): a warning says so."""
    root = tmp_path / "s"
    sparse = np.zeros((12, 16), np.uint16)
    sparse[4, 6] = 2000
    write_png16(root / "depth" / "sparse.png", sparse)
    make_scene(root, edit=_frame0(depth_file_path="depth/sparse.png"))
    assert np.isfinite(load_quiet(root).sensor_depths[0]).sum() == 1
    with pytest.warns(UserWarning, match="no valid depth at the training resolution"):
        scene = load_transforms(root, downscale=2)
    assert not np.isfinite(scene.sensor_depths[0]).any()
