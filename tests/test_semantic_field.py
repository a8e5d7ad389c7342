"""SemanticField's public surface on a small trained field: shapes, conventions, input checks."""

import numpy as np
import pytest
import torch
from threads import assert_concurrent_calls_match

from scenelabel import FREE, UNKNOWN, InputError, SemanticField, build, preset, write_toy_scene
from scenelabel.errors import CheckpointError
from scenelabel.geometry.cameras import cameras_to_dict, opengl_to_opencv
from scenelabel.maps import confidence_from_probs, unit_from_uint8
from scenelabel.maps.visibility import observed_voxels, project_points, scaled_cameras
from scenelabel.query.field import TRAIN_CAMERAS_KEY
from scenelabel.query.mapping import OBSERVED_MAP_PAD


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    root = tmp_path_factory.mktemp("sf")
    scene = write_toy_scene(root / "scene", n_train=14, n_test=2, width=48, height=36)
    config = preset("quick", {"train": {"steps": 150}, "output": {"write_map": False, "write_renders": False}})
    build(scene, root / "out", config, progress=False)
    return SemanticField.load(root / "out")


def test_query_points_shapes_and_ranges(field):
    pts = np.random.default_rng(0).uniform(field.aabb[0] - 0.5, field.aabb[1] + 0.5, (500, 3))
    q = field.query_points(pts)
    assert q.density.shape == (500,) and q.occupancy.shape == (500,) and q.label.shape == (500,)
    assert q.probs.shape == (500, 3) and q.class_ids.tolist() == [1, 3, 7]
    assert np.all((q.occupancy >= 0) & (q.occupancy <= 1))
    inside = np.all((pts >= field.aabb[0]) & (pts <= field.aabb[1]), axis=1)
    assert set(np.unique(q.label[~inside]).tolist()) == {FREE, UNKNOWN}  # FREE where a training camera saw through
    assert np.all(q.density[~inside] == 0) and np.all(q.probs[~inside] == 0)
    assert set(np.unique(q.label[inside]).tolist()) <= {FREE, 1, 3, 7}
    np.testing.assert_allclose(q.probs[inside].sum(-1), 1.0, atol=1e-9)
    np.testing.assert_allclose(q.occupancy, -np.expm1(-q.density * field.occupancy_delta))


def test_torch_input_and_single_point(field):
    a = field.query_points(torch.tensor([[0.0, 0.0, 0.1]]))
    b = field.query_points(np.array([0.0, 0.0, 0.1]))
    np.testing.assert_array_equal(a.density, b.density)


@pytest.mark.parametrize(
    "bad,match",
    [(np.zeros((4, 2)), r"shape \(N, 3\)"), (np.array([[0.0, np.nan, 0.0]]), "non-finite"), (np.full((1, 3), np.inf), "non-finite")],
)
def test_bad_query_inputs(field, bad, match):
    with pytest.raises(InputError, match=match):
        field.query_points(bad)
    with pytest.raises(InputError, match=match):
        field.query_rays(bad, np.ones_like(bad))


def test_query_rays_direction_length_does_not_matter(field):
    o = np.array([[0.0, -2.0, 1.5], [1.0, 1.0, 1.0]])
    d = np.array([[0.0, 1.0, -0.8], [-0.5, -0.4, -1.0]])
    a = field.query_rays(o, d)
    b = field.query_rays(o, d * 7.5)
    np.testing.assert_allclose(a.depth, b.depth, rtol=1e-5)
    np.testing.assert_array_equal(a.label, b.label)
    assert a.rgb.shape == (2, 3) and a.probs.shape == (2, 3)
    with pytest.raises(InputError, match="zero-length"):
        field.query_rays(o, np.zeros((2, 3)))


def test_near_far_limits_depth(field):
    o = np.array([[0.0, -2.0, 1.5]])
    d = np.array([[0.0, 1.0, -0.8]])
    above = field.query_rays(o, d, near=0.5, far=0.6)  # [near, far] lies above the bounds (z > 0.75)
    assert above.label[0] == UNKNOWN and above.depth[0] == np.inf
    r = field.query_rays(o, d, near=1.3, far=1.5)  # inside the bounds: a hit within [near, far], or none
    hit = r.opacity[0] >= 0.5
    assert r.label[0] != UNKNOWN
    assert (hit and 1.3 - 1e-6 <= r.depth[0] <= 1.5 + 1e-6) or (not hit and r.depth[0] == np.inf and r.label[0] == FREE)
    down = field.query_rays([[0.5, -1.0, 1.5]], [[0.0, 0.0, -1.0]], near=0.5)  # on to the floor (or a box on it)
    assert down.label[0] >= 0 and 0.5 < down.depth[0] < 1.5 + 0.17


def test_render_shapes_conventions_and_smoothing(field):
    c2w_gl = np.eye(4)
    c2w_gl[:3, 3] = [0.0, 0.0, 3.0]  # OpenGL: looks down -z, i.e. at the floor
    img = field.render(c2w_gl, 16, 12, 14.0, convention="opengl")
    assert img.rgb.shape == (12, 16, 3) and img.depth.shape == (12, 16) and img.label.shape == (12, 16)
    c2w_cv = opengl_to_opencv(c2w_gl)
    same = field.render(c2w_cv, 16, 12, 14.0)
    np.testing.assert_allclose(img.depth, same.depth, rtol=1e-5)
    smooth = field.render(c2w_cv, 16, 12, 14.0, smooth_sigma=2.0)
    np.testing.assert_allclose(smooth.probs.sum(-1), 1.0, atol=1e-9)
    with pytest.raises(InputError, match="convention"):
        field.render(c2w_cv, 4, 4, 4.0, convention="blender")


def test_concurrent_queries_match_sequential(field):
    pts = np.random.default_rng(1).uniform(field.aabb[0], field.aabb[1], (4, 2000, 3))
    assert_concurrent_calls_match(lambda p: field.query_points(p).density, pts)


def test_density_only_reads_are_the_semantic_reads_density(field):
    """sigmas_n (a map's sub-samples) gives sigmas_and_logits_n's σ, 0 where the grid holds space empty."""
    rng = np.random.default_rng(2)
    pts_n = field.frame.to_normalised(rng.uniform(*field.aabb, size=(3000, 3)))
    sig_n, _ = field.sigmas_and_logits_n(pts_n)
    density_only = field.sigmas_n(pts_n)
    np.testing.assert_allclose(density_only, sig_n, rtol=1e-5, atol=1e-6)
    empty = ~field.occupancy(torch.as_tensor(pts_n, dtype=torch.float32)).numpy()
    assert empty.any() and np.all(density_only[empty] == 0)


def test_occupancy_map_bounds_and_codes(field):
    occ = field.occupancy_map(voxel_size=0.1, bounds=np.array([[-0.5, -0.5, 0.0], [0.5, 0.5, 0.5]]))
    assert occ.voxel_size == 0.1 and occ.occupancy_delta == 0.1
    assert occ.shape == (10, 10, 5)
    assert set(np.unique(occ.label).tolist()) <= {FREE, UNKNOWN, 1, 3, 7}
    with pytest.raises(InputError, match="voxel_size"):
        field.occupancy_map(voxel_size=-1.0)


def test_map_voxels_are_read_coarse_to_fine_as_the_rule_says(field):
    """docs/conventions.md, "Density and occupancy": σ of a map voxel is the largest over its n³
    sub-samples where its centre or one of its 26 neighbours' centres has occupancy >=
    REFINE_OCCUPANCY and not all 27 are occupied, its centre's elsewhere; a plain loop over voxels
    through query_points."""
    from scenelabel.query.answers import OCCUPIED_THRESHOLD
    from scenelabel.query.mapping import REFINE_OCCUPANCY, subsample_offsets

    voxel, box = 0.1, np.array([[-0.6, -0.6, -0.1], [0.6, 0.6, 0.5]])
    occ = field.occupancy_map(voxel_size=voxel, bounds=box, visibility=False)
    offsets = subsample_offsets(field, voxel)
    assert len(offsets) > 1

    def density(points):
        return field.query_points(np.asarray(points, np.float64).reshape(-1, 3)).density  # 0 outside the bounds

    expected = np.zeros(occ.shape)
    refined = np.zeros(occ.shape, bool)
    enclosed = np.zeros(occ.shape, bool)
    steps = [-1, 0, 1]
    for ijk in np.ndindex(*occ.shape):
        centre = occ.origin + voxel * np.asarray(ijk, np.float64)
        near = [centre + voxel * np.array([a, b, c], np.float64) for a in steps for b in steps for c in steps]
        near_occ = -np.expm1(-density(near) * voxel)
        enclosed[ijk] = near_occ.min() >= OCCUPIED_THRESHOLD
        refined[ijk] = near_occ.max() >= REFINE_OCCUPANCY and not enclosed[ijk]
        sigma = density(centre + offsets).max() if refined[ijk] else density(centre)[0]
        expected[ijk] = -np.expm1(-sigma * voxel)
    assert 0 < refined.mean() < 1 and enclosed.any()  # every branch is exercised
    np.testing.assert_allclose(occ.occupancy, expected, rtol=1e-4, atol=1e-6)
    # the answer does not depend on how the lattice is split into blocks (each block reads a halo)
    small_blocks = field.occupancy_map(voxel_size=voxel, bounds=box, chunk=3, visibility=False)
    np.testing.assert_allclose(small_blocks.occupancy, occ.occupancy, rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(small_blocks.label, occ.label)


def test_incompatible_checkpoint_version(tmp_path):
    data = {"format": "scenelabel.checkpoint", "format_version": 999}
    path = tmp_path / "checkpoint.pt"
    torch.save(data, path)
    with pytest.raises(CheckpointError, match="not supported"):
        SemanticField.load(tmp_path)
    path.write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="unreadable"):
        SemanticField.load(path)
    with pytest.raises(CheckpointError, match="no checkpoint"):
        SemanticField.load(tmp_path / "missing")


def test_geometry_edge_cases(field):
    lo, hi = field.aabb
    # a ray starting inside the bounds (and inside the floor slab) answers by the contract
    inside = field.query_rays([[0.0, 0.0, -0.01]], [[0.0, 0.0, 1.0]])
    assert inside.label[0] != UNKNOWN and np.isfinite(inside.depth[0]) == (inside.label[0] >= 0)
    assert inside.depth[0] >= 0
    # a camera exactly at the bounds' corner, looking at the centre
    corner = hi.copy()
    r = field.query_rays([corner], [0.5 * (lo + hi) - corner])
    assert r.label[0] != UNKNOWN and np.isfinite(r.depth[0])
    # a ray pointing away from the bounds: UNKNOWN, no depth (the ray contract)
    away = field.query_rays([hi + 1.0], [[1.0, 1.0, 1.0]])
    assert away.label[0] == UNKNOWN and away.depth[0] == np.inf


def test_memory_does_not_grow_over_many_queries(field):
    import tracemalloc

    pts = np.random.default_rng(2).uniform(field.aabb[0], field.aabb[1], (64, 3))
    for _ in range(200):  # warm up caches and allocators
        field.query_points(pts)
    rss_before = resident_bytes()
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    for _ in range(10_000):
        field.query_points(pts)
    after = tracemalloc.take_snapshot()
    tracemalloc.stop()
    grown = sum(stat.size_diff for stat in after.compare_to(before, "filename"))
    assert grown < 1_000_000, grown  # Python-side growth under 1 MB after 10,000 calls
    assert resident_bytes() - rss_before < 50_000_000  # and the process (torch included) under 50 MB


def resident_bytes() -> int:
    """The process's resident set size from /proc (Linux)."""
    import os

    with open(f"/proc/{os.getpid()}/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


# ---------------------------------------------------------------------------- observed space (maps)

MAP_BOX = np.array([[-1.0, -1.0, -0.15], [1.0, 1.0, 0.7]])


def field_with_meta(field, **changes) -> SemanticField:
    """The same trained field with checkpoint entries replaced (None removes one)."""
    meta = {k: v for k, v in {**field.meta, **changes}.items() if v is not None}
    return SemanticField(field.model, field.occupancy, field.frame, field.class_map, meta)


def voxel_centres(m) -> np.ndarray:
    """[n_voxels, 3] world centres in C order of the map's arrays."""
    return m.world_from_index(np.stack(np.meshgrid(*[np.arange(n) for n in m.shape], indexing="ij"), -1).reshape(-1, 3))


def test_build_stores_training_cameras(field):
    cams = field.training_cameras()
    assert len(cams) == 14 and cams.c2w.shape == (14, 4, 4)
    assert cams.width.tolist() == [48] * 14 and np.all(np.isfinite(cams.far))
    np.testing.assert_allclose(cams.c2w[:, 3], [[0, 0, 0, 1]] * 14)


def test_occupancy_map_visibility_only_adds_unknown_and_surfaces(field):
    """The visibility rule changes a voxel only to UNKNOWN, or a FREE one to the class of its most
    probable channel where a camera's surface lies in it."""
    vis = field.occupancy_map(voxel_size=0.1, bounds=MAP_BOX)
    plain = field.occupancy_map(voxel_size=0.1, bounds=MAP_BOX, visibility=False)
    assert vis.unknown_rule == "visibility" and plain.unknown_rule == "bounds"
    known = vis.label != UNKNOWN
    assert known.any() and (~known).any() and np.all(plain.label != UNKNOWN)
    changed = known & (vis.label != plain.label)
    assert np.all(plain.label[changed] == FREE)
    np.testing.assert_array_equal(vis.label[changed], field.class_ids[plain.probs[changed].argmax(-1)])
    np.testing.assert_array_equal(vis.occupancy[changed], 0.5)  # raised to the threshold
    np.testing.assert_array_equal(vis.label >= 0, vis.occupied)
    same = known & ~changed
    np.testing.assert_array_equal(vis.occupancy[same], plain.occupancy[same])
    # probs and confidence: per class id, quantised, 0 where UNKNOWN
    assert vis.probs.shape == vis.shape + (3,) and vis.probs.dtype == np.uint8
    np.testing.assert_array_equal(vis.class_ids, field.class_ids)
    rows = unit_from_uint8(vis.probs[known])
    np.testing.assert_allclose(rows.sum(-1), 1.0, atol=3 / 255)
    # the confidence came from the unquantised probabilities; entropy is steep near 0, so a code
    # step of a small probability moves it by up to ~0.02
    np.testing.assert_allclose(unit_from_uint8(vis.confidence[known]), confidence_from_probs(rows), atol=0.05)
    assert np.all(vis.probs[~known] == 0) and np.all(vis.confidence[~known] == 0)


def test_occupancy_map_unknown_outside_the_only_camera(field):
    cams = field.training_cameras()
    one = field_with_meta(field, **{TRAIN_CAMERAS_KEY: cameras_to_dict(cams[[0]])})
    m = one.occupancy_map(voxel_size=0.1)
    plain = one.occupancy_map(voxel_size=0.1, visibility=False)
    centres = voxel_centres(m)
    cam = scaled_cameras(cams[[0]])
    uv, z, dist = project_points(centres, cam.c2w[0], cam.fx[0], cam.fy[0], cam.cx[0], cam.cy[0])
    with np.errstate(invalid="ignore"):
        in_frustum = (
            (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width[0]) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height[0])
            & (dist >= cam.near[0]) & (dist <= cam.far[0])
        )
    label = m.label.reshape(-1)
    assert in_frustum.any() and (~in_frustum).any()
    assert np.all(label[~in_frustum] == UNKNOWN)
    assert np.any(label[in_frustum] == FREE)
    # exactly observed_voxels on the map's own opacities (the map covers all the bounds): the
    # camera's surfaces are occupied, with their voxel's most probable class
    expected, occupied = observed_voxels(plain.occupancy, plain.origin, plain.voxel_size, cam)
    np.testing.assert_array_equal(m.label != UNKNOWN, expected)
    np.testing.assert_array_equal(m.label >= 0, expected & occupied)
    same = expected & (plain.label >= 0)
    np.testing.assert_array_equal(m.label[same], plain.label[same])
    surface = expected & occupied & (plain.label == FREE)
    assert surface.any()  # the short-trained field's surfaces are partly fog
    np.testing.assert_array_equal(m.label[surface], field.class_ids[plain.probs[surface].argmax(-1)])


def test_cropped_map_is_occluded_by_surfaces_outside_it(field):
    """A map of the slab under the floor only: the floor, outside the map, still hides it."""
    crop = np.array([[-1.0, -1.0, -0.15], [1.0, 1.0, -0.05]])
    m = field.occupancy_map(voxel_size=0.05, bounds=crop)
    plain = field.occupancy_map(voxel_size=0.05, bounds=crop, visibility=False)
    without_floor, _ = observed_voxels(plain.occupancy, plain.origin, plain.voxel_size, scaled_cameras(field.training_cameras()))
    assert without_floor.mean() > 0.5  # the map alone has no floor to hide the slab
    assert np.mean(m.label == UNKNOWN) >= 0.9  # the short-trained floor has a few holes


def test_the_default_map_is_the_modelled_lattice_cut_to_the_observed_geometry(field):
    """Bounds found from observed points are stored as their extent (``observed_bounds``); the default
    map holds the voxels of the modelled bounds' lattice that meet it, padded by OBSERVED_MAP_PAD of
    its longest side: the same voxels and answers as the whole map's, without the space beyond."""
    assert field.observed_bounds is None  # the toy's files give its box: its maps cover all of it
    observed = np.array([[-0.6, -0.5, 0.0], [0.4, 0.3, 0.5]])
    cut = field_with_meta(field, observed_bounds=observed.tolist())
    whole = field.occupancy_map(voxel_size=0.1, visibility=False)
    part = cut.occupancy_map(voxel_size=0.1, visibility=False)
    offset = np.round((part.origin - whole.origin) / 0.1).astype(int)
    np.testing.assert_allclose(part.origin, whole.origin + 0.1 * offset, atol=1e-9)
    block = tuple(slice(o, o + n) for o, n in zip(offset, part.shape))
    np.testing.assert_array_equal(part.label, whole.label[block])
    np.testing.assert_array_equal(part.probs, whole.probs[block])
    np.testing.assert_array_equal(part.occupancy, whole.occupancy[block])
    pad = OBSERVED_MAP_PAD * 1.0  # the observed extent's longest side is 1 m
    lo, hi = part.origin - 0.05, part.origin + 0.1 * (np.asarray(part.shape) - 0.5)
    assert np.all(lo <= observed[0] - pad) and np.all(lo > observed[0] - pad - 0.1)
    assert np.all(hi >= observed[1] + pad) and np.all(hi < observed[1] + pad + 0.1)
    assert np.prod(part.shape) < 0.5 * np.prod(whole.shape)
    assert cut.occupancy_map(voxel_size=0.1, bounds=cut.aabb, visibility=False) == whole  # bounds= still rules


def test_old_checkpoint_falls_back_to_bounds(field):
    old = field_with_meta(field, **{TRAIN_CAMERAS_KEY: None})
    assert old.training_cameras() is None
    m = old.occupancy_map(voxel_size=0.1, bounds=MAP_BOX)
    assert m.unknown_rule == "bounds" and m.attributes()["unknown_rule"] == "bounds"
    assert m == field.occupancy_map(voxel_size=0.1, bounds=MAP_BOX, visibility=False)


def test_render_keeps_rays_within_near_far_and_render_camera_passes_the_cameras_range(field):
    """Rays of a render span [near, far] when given; render_camera gives a camera's own depth range
    (LLFF bounds), as its training rays had it."""
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, 0.0, 3.0]
    img = field.render(opengl_to_opencv(c2w), 16, 12, 14.0, near=2.0, far=2.5)
    assert np.all(img.depth >= 2.0 - 1e-5) and np.all(img.depth <= 2.5 + 1e-5)
    cams = field.training_cameras()
    bounded = type(cams)(**{**vars(cams), "near": np.full(len(cams), 2.0), "far": np.full(len(cams), 2.5)})
    got = field.render_camera(bounded, 0)
    cam = cams[0]
    want = field.render(cam.c2w[0], int(cam.width[0]), int(cam.height[0]), (cam.fx[0], cam.fy[0]), cam.cx[0], cam.cy[0],
                        distortion=cam.distortion[0], near=2.0, far=2.5)
    np.testing.assert_array_equal(got.depth, want.depth)
    unbounded = field.render_camera(type(cams)(**{**vars(cams), "near": np.full(len(cams), np.nan), "far": np.full(len(cams), np.inf)}), 0)
    assert not np.array_equal(unbounded.depth, got.depth)


def test_render_camera_of_a_fisheye_uses_its_model(field):
    """render_camera passes a camera's lens model: a fisheye renders as render(camera_model="fisheye")
    does, not as the pinhole with the same intrinsics."""
    cams = field.training_cameras()
    k = np.array([0.02, -0.001, 0.0, 0.0])
    fisheyes = type(cams)(**{**vars(cams), "model": np.full(len(cams), "fisheye"), "distortion": np.tile(k, (len(cams), 1))})
    got = field.render_camera(fisheyes, 0)
    cam = cams[0]
    near, far = (float(v[0]) if np.isfinite(v[0]) else None for v in (cam.near, cam.far))
    want = field.render(cam.c2w[0], int(cam.width[0]), int(cam.height[0]), (cam.fx[0], cam.fy[0]), cam.cx[0], cam.cy[0],
                        distortion=k, near=near, far=far, camera_model="fisheye")
    np.testing.assert_array_equal(got.depth, want.depth)
    assert not np.array_equal(got.depth, field.render_camera(cams, 0).depth)


def test_reprs_are_one_short_line(field):
    """print() of a field, its baked twin, answers and maps says what they are, not their arrays."""
    from scenelabel import BakedField

    rng = np.random.default_rng(0)
    xyz = rng.uniform(field.aabb[0], field.aabb[1], (5000, 3))
    answers = [field, BakedField.from_field(field), field.query_points(xyz), field.query_rays(xyz, np.tile([1.0, 0, 0], (5000, 1)))]
    answers.append(field.occupancy_map(0.2))
    for obj in answers:
        text = repr(obj)
        assert "\n" not in text and len(text) < 400 and text.startswith(type(obj).__name__ + "("), text
    assert "points=5000" in repr(answers[2]) and "rays=5000" in repr(answers[3])
    assert f"voxel_size={0.2:g}" in repr(answers[4])
