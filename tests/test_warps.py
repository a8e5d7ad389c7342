"""Warps (box and forward-facing frustum) against naive float64 references; forward-facing detection."""

import math

import numpy as np
import pytest
import torch

from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.frame import frustum_points
from scenelabel.geometry.warps import BoxWarp, ForwardWarp, capture_reference, forward_facing_reference, warp_from_dict


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def naive_forward(x, centre, rotation, tan_xy, near, far):
    """Float64 per-point loop of ForwardWarp's docstring formula."""
    out = np.zeros((len(x), 3))
    inv_far = 0.0 if math.isinf(far) else 1.0 / far
    for i in range(len(x)):
        p = rotation.T @ (x[i] - centre)
        if p[2] <= 1e-6:  # behind (or at) the reference camera
            out[i, 2] = -2.0
            continue
        out[i, 0] = p[0] / (p[2] * tan_xy[0])
        out[i, 1] = p[1] / (p[2] * tan_xy[1])
        out[i, 2] = 2.0 * (1.0 / near - 1.0 / p[2]) / (1.0 / near - inv_far) - 1.0
    return out


def inside_cube(unit):
    return (unit.abs() <= 1.0).all(-1)


# ------------------------------------------------------------------ BoxWarp


def test_box_warp_maps_corners_to_unit_cube_and_round_trips():
    aabb = torch.tensor([[-1.0, -0.5, 0.2], [3.0, 0.5, 0.7]])
    warp = BoxWarp(aabb)
    corners = torch.tensor([[aabb[a, 0], aabb[b, 1], aabb[c, 2]] for a in (0, 1) for b in (0, 1) for c in (0, 1)])
    expected = torch.tensor([[2.0 * a - 1, 2.0 * b - 1, 2.0 * c - 1] for a in (0, 1) for b in (0, 1) for c in (0, 1)])
    torch.testing.assert_close(warp(corners), expected, atol=1e-6, rtol=0)
    torch.testing.assert_close(warp(0.5 * (aabb[0] + aabb[1])[None]), torch.zeros(1, 3), atol=1e-6, rtol=0)
    pts = torch.rand(500, 3, generator=torch.Generator().manual_seed(0)) * 6 - 3  # inside and outside
    torch.testing.assert_close(warp.inverse(warp(pts)), pts, atol=1e-5, rtol=0)
    unit = torch.rand(500, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1
    torch.testing.assert_close(warp(warp.inverse(unit)), unit, atol=1e-5, rtol=0)
    assert warp.spacing == "uniform" and warp.kind == "box"


def test_box_warp_dict_round_trip():
    warp = BoxWarp(torch.tensor([[-1.0, -2.0, -3.0], [1.0, 2.0, 0.5]]))
    again = warp_from_dict(warp.to_dict())
    assert isinstance(again, BoxWarp)
    torch.testing.assert_close(again.aabb, warp.aabb, atol=0, rtol=0)


# ------------------------------------------------------------------ ForwardWarp

REFERENCES = {
    "identity": (np.zeros(3), np.eye(3), np.array([0.6, 0.4]), 0.5, 8.0),
    "rotated": (np.array([0.3, -0.2, 0.1]), rot_z(0.4) @ rot_y(-0.7) @ rot_x(0.25), np.array([0.9, 0.5]), 0.2, 3.0),
    "far_inf": (np.array([-0.1, 0.2, 0.0]), rot_y(0.3) @ rot_x(-0.2), np.array([0.7, 0.7]), 0.3, math.inf),
}


@pytest.mark.parametrize("name", sorted(REFERENCES))
def test_forward_warp_matches_naive_loop(name):
    centre, rotation, tan_xy, near, far = REFERENCES[name]
    warp = ForwardWarp(centre, rotation, tan_xy, near, far)
    rng = np.random.default_rng(0)
    x = np.concatenate(
        [
            rng.uniform(-4, 4, (400, 3)),  # many behind / beside the camera
            centre + (rng.uniform(-0.5, 0.5, (200, 3)) + [0, 0, 2.0]) @ rotation.T,  # in front
        ]
    )
    x32 = x.astype(np.float32).astype(np.float64)  # what the float32 warp actually sees
    ref = naive_forward(x32, centre, rotation, tan_xy.astype(np.float32).astype(np.float64), near, far)
    got = warp(torch.tensor(x32, dtype=torch.float32)).double().numpy()
    assert np.isfinite(got).all()
    # float32 rounding of near-zero depths can flip front / behind or blow up 1 / depth: keep clear of it
    depth = (x32 - centre) @ rotation[:, 2]
    clear = np.abs(depth) > 1e-2
    assert clear.sum() > 550
    front = clear & (depth > 0)
    behind = clear & (depth < 0)
    assert front.sum() > 200 and behind.sum() > 100
    np.testing.assert_array_equal(got[behind, 2], -2.0)
    # relative tolerance (u, v and s grow as 1 / depth near the camera plane)
    scale = np.maximum(1.0, np.abs(ref[front]))
    np.testing.assert_allclose(got[front] / scale, ref[front] / scale, atol=1e-4, rtol=0)


@pytest.mark.parametrize("name", sorted(REFERENCES))
def test_forward_warp_near_far_axis_and_round_trip(name):
    centre, rotation, tan_xy, near, far = REFERENCES[name]
    warp = ForwardWarp(centre, rotation, tan_xy, near, far)
    axis = rotation[:, 2]
    at_near = torch.tensor(centre + near * axis, dtype=torch.float32)[None]
    np.testing.assert_allclose(warp(at_near).numpy(), [[0.0, 0.0, -1.0]], atol=1e-5)
    if math.isfinite(far):
        at_far = torch.tensor(centre + far * axis, dtype=torch.float32)[None]
        np.testing.assert_allclose(warp(at_far).numpy(), [[0.0, 0.0, 1.0]], atol=1e-5)
    else:  # the cube reaches infinity: very far points approach s = 1 from below
        very_far = torch.tensor(centre + 1e6 * axis, dtype=torch.float32)[None]
        s = warp(very_far)[0, 2].item()
        assert 0.999 < s <= 1.0
    # frustum corners at near and (finite) far map to the cube's corners
    for t, s in ((near, -1.0), (far, 1.0)):
        if not math.isfinite(t):
            continue
        for su in (-1, 1):
            for sv in (-1, 1):
                p = centre + rotation @ np.array([su * tan_xy[0] * t, sv * tan_xy[1] * t, t])
                np.testing.assert_allclose(
                    warp(torch.tensor(p, dtype=torch.float32)[None]).numpy(), [[su, sv, s]], atol=1e-4
                )
    # inverse(forward(x)) == x for points inside the frustum
    g = torch.Generator().manual_seed(3)
    unit = torch.rand(2000, 3, generator=g, dtype=torch.float64) * 1.98 - 0.99
    if not math.isfinite(far):
        unit[:, 2] = unit[:, 2].clamp(max=0.9)  # keep depths moderate (z = near / (1 - (s+1)/2))
    x = warp.inverse(unit.float()).double()
    p = (x.numpy() - centre) @ rotation
    assert np.all(p[:, 2] >= near * (1 - 1e-4))
    if math.isfinite(far):
        assert np.all(p[:, 2] <= far * (1 + 1e-4))
    back = warp(x.float())
    torch.testing.assert_close(back.double(), unit, atol=5e-4, rtol=0)
    again = warp.inverse(back).double()
    z = torch.tensor(p[:, 2:3])
    torch.testing.assert_close(again / z, x / z, atol=1e-4, rtol=0)  # relative to depth
    assert bool(inside_cube(back).all())


def test_forward_warp_far_inf_inverse_at_s_one_is_finite():
    centre, rotation, tan_xy, near, far = REFERENCES["far_inf"]
    warp = ForwardWarp(centre, rotation, tan_xy, near, far)
    np.testing.assert_array_equal(warp.inv_range.numpy(), [1.0 / np.float32(near), 0.0])
    unit = torch.tensor([[0.0, 0.0, 1.0], [1.0, -1.0, 1.0], [0.5, 0.5, 0.999999]])
    x = warp.inverse(unit)
    assert torch.isfinite(x).all()
    depth = (x.double().numpy() - centre) @ rotation[:, 2]
    assert depth[0] > 1e9 and depth[1] > 1e9  # "the point at infinity", finite
    assert depth[2] > near


def test_forward_warp_points_behind_or_at_centre_are_finite_and_outside():
    for name in sorted(REFERENCES):
        centre, rotation, tan_xy, near, far = REFERENCES[name]
        warp = ForwardWarp(centre, rotation, tan_xy, near, far)
        axis = rotation[:, 2]
        pts = np.stack(
            [
                centre,  # exactly at the camera centre
                centre - 1e-3 * axis,
                centre - 5.0 * axis + 3.0 * rotation[:, 0],
                centre + 1e-9 * axis,  # in front, but within BEHIND_EPS
                centre + 1e-3 * rotation[:, 0],  # in the camera plane, beside the centre
                centre - 1e30 * axis,
            ]
        )
        unit = warp(torch.tensor(pts, dtype=torch.float32))
        assert torch.isfinite(unit).all(), (name, unit)
        assert not bool(inside_cube(unit).any()), (name, unit)
        assert torch.all(unit[:, 2] == -2.0)


def test_forward_warp_dict_round_trip():
    for name in sorted(REFERENCES):
        centre, rotation, tan_xy, near, far = REFERENCES[name]
        warp = ForwardWarp(centre, rotation, tan_xy, near, far)
        data = warp.to_dict()
        assert data["kind"] == "forward"
        if math.isinf(far):
            assert data["far"] == math.inf
        else:
            assert data["far"] == pytest.approx(far, rel=1e-6)
        assert data["near"] == pytest.approx(near, rel=1e-6)
        again = warp_from_dict(data)
        assert isinstance(again, ForwardWarp) and again.spacing == "disparity"
        for key in ("centre", "rotation", "tan_xy", "inv_range"):
            torch.testing.assert_close(getattr(again, key), getattr(warp, key), atol=0, rtol=1e-6)
        pts = torch.rand(100, 3, generator=torch.Generator().manual_seed(5)) * 4 - 2
        torch.testing.assert_close(again(pts), warp(pts), atol=1e-6, rtol=1e-6)
    with pytest.raises(ValueError, match="unknown warp kind"):
        warp_from_dict({"kind": "ndc"})


@pytest.mark.parametrize("near, far", [(1.0, 1.0), (2.0, 1.0), (0.0, 1.0), (-1.0, 1.0), (-1.0, math.inf)])
def test_forward_warp_rejects_bad_near_far(near, far):
    with pytest.raises(ValueError, match="0 < near < far"):
        ForwardWarp(np.zeros(3), np.eye(3), [1.0, 1.0], near, far)


# ------------------------------------------------------------------ forward_facing_reference


def _cams(c2w_cv, near=0.5, far=6.0, width=40, height=30, focal=35.0):
    return Cameras.create(np.stack(c2w_cv), focal, focal, width / 2, height / 2, width, height, near=near, far=far)


def _pose(rotation, centre):
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = rotation, centre
    return c2w


def llff_rig():
    """5 cameras looking roughly +z (small yaw / pitch) from a small patch, OpenCV axes."""
    yaws = [-0.15, -0.07, 0.0, 0.08, 0.14]
    centres = [[-0.4, 0.05, 0.0], [-0.2, -0.05, 0.02], [0.0, 0.0, 0.0], [0.2, 0.04, -0.02], [0.4, -0.03, 0.01]]
    return [_pose(rot_y(a) @ rot_x(0.03 * (i - 2)), c) for i, (a, c) in enumerate(zip(yaws, centres))]


def test_forward_facing_rig_gets_a_reference_that_holds_every_frustum():
    cams = _cams(llff_rig())
    pts = frustum_points(cams, cams.near, cams.far)
    ref = forward_facing_reference(cams, pts)
    assert ref is not None
    np.testing.assert_allclose(ref["rotation"].T @ ref["rotation"], np.eye(3), atol=1e-9)
    assert np.linalg.det(ref["rotation"]) == pytest.approx(1.0)
    assert ref["rotation"][:, 2] @ np.array([0.0, 0.0, 1.0]) > 0.99  # looks along +z
    np.testing.assert_allclose(ref["centre"], cams.centres.mean(0))
    assert 0 < ref["near"] < ref["far"] < np.inf
    warp = ForwardWarp(**ref)
    unit = warp(torch.tensor(pts, dtype=torch.float32))
    assert bool(inside_cube(unit).all()), unit[~inside_cube(unit)]
    # the frustum is used well: some point comes close to each face of the cube
    assert float(unit[:, 0].abs().max()) > 0.8 and float(unit[:, 1].abs().max()) > 0.8
    assert float(unit[:, 2].min()) < -0.8 and float(unit[:, 2].max()) > 0.8
    # and every camera's own rays in between map inside too
    rng = np.random.default_rng(0)
    t = rng.uniform(cams.near[0], cams.far[0], (len(cams), 50))
    dirs = np.stack([rng.uniform(-20, 20, 50) / 35.0, rng.uniform(-15, 15, 50) / 35.0, np.ones(50)], -1)
    inner = np.concatenate(
        [cams.centres[i] + (t[i, :, None] * dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)) @ cams.c2w[i, :3, :3].T for i in range(len(cams))]
    )
    assert bool(inside_cube(warp(torch.tensor(inner, dtype=torch.float32))).all())


def _same_reference(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_allclose(a[key], b[key], rtol=1e-12, atol=1e-12, err_msg=key)


def test_capture_reference_narrows_its_depths_to_the_modelled_box():
    cams = _cams(llff_rig(), near=0.5, far=6.0)
    wide = capture_reference(cams)
    _same_reference(wide, forward_facing_reference(cams, frustum_points(cams, cams.near, cams.far)))
    box = np.array([[-2.0, -1.5, 1.0], [2.0, 1.5, 4.0]])  # the scene between 1 and 4 in front of the rig
    narrow = capture_reference(cams, box)
    corners = np.stack(np.meshgrid(*box.T, indexing="ij"), -1).reshape(-1, 3)
    depth = (corners - narrow["centre"]) @ narrow["rotation"][:, 2]
    assert narrow["near"] == pytest.approx(depth.min()) and narrow["far"] == pytest.approx(depth.max())
    assert wide["near"] < narrow["near"] < narrow["far"] < wide["far"]
    np.testing.assert_array_equal(narrow["tan_xy"], wide["tan_xy"])  # every view's angles still covered
    huge = np.array([[-50.0, -50.0, -50.0], [50.0, 50.0, 50.0]])  # a box past the frusta changes nothing
    _same_reference(capture_reference(cams, huge), wide)
    assert capture_reference(_cams([_pose(rot_y(a), [0, 0, 0]) for a in (0.0, 1.6, 3.2)]), box) is None


def test_orbit_is_not_forward_facing():
    c2ws = []
    for k in range(8):
        a = 2 * math.pi * k / 8
        eye = np.array([3 * math.cos(a), 3 * math.sin(a), 0.0])
        z = -eye / np.linalg.norm(eye)  # looking at the origin
        y = np.array([0.0, 0.0, -1.0])
        x = np.cross(y, z)
        c2ws.append(_pose(np.stack([x, y, z], 1), eye))
    cams = _cams(c2ws, near=1.0, far=5.0)
    assert forward_facing_reference(cams, frustum_points(cams, cams.near, cams.far)) is None


def test_a_point_behind_the_mean_camera_is_not_forward_facing():
    cams = _cams(llff_rig())
    pts = frustum_points(cams, cams.near, cams.far)
    assert forward_facing_reference(cams, pts) is not None
    behind = np.concatenate([pts, [[0.0, 0.0, -1.0]]])
    assert forward_facing_reference(cams, behind) is None
    ref = forward_facing_reference(cams, pts)
    beside = ref["centre"] + 2.0 * ref["rotation"][:, 0] - 1e-6 * ref["rotation"][:, 2]  # just behind, off-axis
    assert forward_facing_reference(cams, np.concatenate([pts, [beside]])) is None


def test_cameras_opposite_ways_are_not_forward_facing():
    cams = _cams([_pose(np.eye(3), [0.0, 0.0, 0.0]), _pose(rot_y(math.pi), [0.0, 0.0, 1.0])])
    assert forward_facing_reference(cams, frustum_points(cams, cams.near, cams.far)) is None


def test_forward_warp_clip_limits_rays_to_its_slab():
    """A camera inside the scene box (t_min = 0): the interval starts at the warp's near plane."""
    warp = ForwardWarp([0.0, 0.0, 0.0], rot_y(0.3), [1.0, 1.0], near=0.5, far=4.0)
    axis = warp.rotation[:, 2]
    origins = torch.stack([torch.zeros(3), -0.25 * axis, torch.zeros(3), torch.zeros(3)])  # [4, 3]
    off_axis = torch.nn.functional.normalize(axis + 0.5 * warp.rotation[:, 0], dim=0)
    directions = torch.stack([axis, axis, off_axis, -axis])
    t_min, t_max = torch.zeros(4), torch.full((4,), 10.0)
    lo, hi = warp.clip(origins, directions, t_min, t_max)
    cos = float(off_axis @ axis)
    torch.testing.assert_close(lo[:3], torch.tensor([0.5, 0.75, 0.5 / cos]))
    torch.testing.assert_close(hi[:3], torch.tensor([4.0, 4.25, 4.0 / cos]))
    assert hi[3] <= lo[3]  # looking backwards from outside the slab: nothing to march
    # an interval already tighter than the slab stays as it is; the box warp never clips
    lo, hi = warp.clip(origins[:1], directions[:1], torch.tensor([1.0]), torch.tensor([2.0]))
    assert lo.item() == 1.0 and hi.item() == 2.0
    box = BoxWarp(torch.tensor([[-1.0] * 3, [1.0] * 3]))
    assert box.clip(origins, directions, t_min, t_max) == (t_min, t_max)


def test_a_point_in_the_mean_camera_plane_is_not_forward_facing():
    cams = _cams(llff_rig())
    points = np.concatenate([frustum_points(cams, cams.near, cams.far), cams.centres.mean(0, keepdims=True) + [0, 0, 1e-5]])
    assert forward_facing_reference(cams, points) is None
