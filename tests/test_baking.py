"""Baked queries: the kernels against naive float64 loops and the renderer's own maths, finite at
the extremes, and a baked toy field answering as the field does."""

import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from threads import assert_concurrent_calls_match

from scenelabel import FREE, UNKNOWN, BakedField, InputError, SemanticField
from scenelabel.maps import uint8_from_unit
from scenelabel.query.answers import softmax64
from scenelabel.query.baked import MAX_BAKE_BYTES, composite_baked_rays, trilinear
from scenelabel.render.volume import class_probs_from_weights, depth_from_weights, weights_from_density


def naive_trilinear(values, corner, spacing, p):
    """One point, float64: the 8 corners of its cell blended by the tensor-product weights."""
    shape = np.array(values.shape[:3]) - 1
    x = (np.asarray(p, np.float64) - corner) / spacing
    if np.any(x < 0) or np.any(x > shape):
        return np.zeros(values.shape[3])
    i = np.minimum(np.floor(x).astype(int), shape - 1)
    f = x - i
    out = np.zeros(values.shape[3])
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (f[0] if dx else 1 - f[0]) * (f[1] if dy else 1 - f[1]) * (f[2] if dz else 1 - f[2])
                out += w * values[i[0] + dx, i[1] + dy, i[2] + dz].astype(np.float64)
    return out


def naive_ray(lattice, ray, step, scores, min_trans):
    """One ray, one sample at a time, float64 Python floats: (depth, opacity, probs)."""
    density, class_values, corner, spacing = lattice
    o, d, t_lo, t_hi = ray
    trans, w_sum, wt_sum, acc = 1.0, 0.0, 0.0, np.zeros(class_values.shape[3])
    k, t0 = 0, t_lo
    while t0 < t_hi and trans >= min_trans:
        k += 1
        t1 = min(t_lo + k * step, t_hi)
        tm = 0.5 * (t0 + t1)
        sigma = max(naive_trilinear(density[..., None], corner, spacing, o + tm * d)[0], 0.0)
        alpha = 1.0 - math.exp(-sigma * (t1 - t0))
        w = trans * alpha
        trans *= 1.0 - alpha
        w_sum += w
        wt_sum += w * tm
        v = naive_trilinear(class_values, corner, spacing, o + tm * d)
        acc += w * (v if scores else v / max(v.sum(), 1e-300))  # logits (eq. 3) or probabilities (eq. 7)
        t0 = t1
    far = max(t_hi, 0.0)
    if w_sum <= 1e-10:
        return far, w_sum, np.full(len(acc), 1.0 / len(acc))
    depth = min(max(wt_sum / w_sum, min(t_lo, far)), far)
    return depth, w_sum, softmax64(acc) if scores else acc / w_sum


def random_lattice(rng, shape=(5, 4, 6), n_classes=4, scores=True):
    """(density, class values, corner, spacing): density with 40% of the vertices empty; float32
    logits, or with scores=False their softmax as uint8 codes (what a bake stores)."""
    density = (rng.exponential(3.0, shape) * (rng.uniform(size=shape) > 0.4)).astype(np.float32)
    logits = rng.normal(0, 3, (*shape, n_classes))
    class_values = logits.astype(np.float32) if scores else uint8_from_unit(softmax64(logits))
    return density, class_values, np.array([-1.0, 0.5, 2.0]), 0.25


def random_rays(rng, corner, n=40):
    o = corner + rng.uniform(-0.2, 1.2, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    t_min = rng.uniform(0, 0.3, n)
    return o, d, t_min, t_min + rng.uniform(0.0, 1.5, n)


@pytest.mark.parametrize("dtype", [np.float32, np.uint8])
def test_trilinear_matches_naive_loop(dtype):
    rng = np.random.default_rng(0)
    values = rng.uniform(0, 255, (5, 4, 6, 3)).astype(dtype)
    corner, spacing = np.array([-1.0, 0.5, 2.0]), 0.25
    hi = corner + spacing * (np.array(values.shape[:3]) - 1)
    pts = np.concatenate([
        rng.uniform(corner - 0.1, hi + 0.1, (300, 3)),  # some outside: 0
        corner + spacing * np.array([[0, 0, 0], [4, 3, 5], [2, 1, 3]]),  # vertices (and the far corner)
    ])
    got = trilinear(values, corner, spacing, pts)
    want = np.stack([naive_trilinear(values, corner, spacing, p) for p in pts])
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-4)
    np.testing.assert_array_equal(got[-3:], values[[0, 4, 2], [0, 3, 1], [0, 5, 3]])  # exact at vertices


@pytest.mark.parametrize("scores", [False, True])
def test_points_match_naive_loop(scores):
    """BakedField.query_points: the trilinear class values normalised (uint8 probabilities), or
    their softmax (logits, an eq. 3 lattice); uniform and UNKNOWN outside the bounds."""
    rng = np.random.default_rng(8)
    lattice = random_lattice(rng, scores=scores)
    density, class_values, corner, spacing = lattice
    hi = corner + spacing * (np.array(density.shape) - 1)
    baked = BakedField(lattice, np.stack([corner, hi]), {0: "a", 3: "b", 5: "c", 9: "d"}, (0.1, 0.05, scores))
    pts = rng.uniform(corner - 0.1, hi + 0.1, (300, 3))
    got = baked.query_points(pts)
    for p, sigma, probs, label in zip(pts, got.density, got.probs, got.label):
        if not np.all((p >= corner) & (p <= hi)):
            assert label == UNKNOWN and sigma == 0 and np.all(probs == 0)
            continue
        v = naive_trilinear(class_values, corner, spacing, p)
        want = softmax64(v) if scores else v / v.sum()
        assert sigma == pytest.approx(max(naive_trilinear(density[..., None], corner, spacing, p)[0], 0.0), rel=1e-6, abs=1e-9)
        np.testing.assert_allclose(probs, want, atol=1e-9)
        occupied = 1 - math.exp(-sigma * 0.1) >= 0.5
        assert label == ([0, 3, 5, 9][int(np.argmax(want))] if occupied else FREE)


@pytest.mark.parametrize("scores", [False, True])
@pytest.mark.parametrize("min_trans", [0.0, 1e-4])
def test_rays_match_naive_loop(scores, min_trans):
    rng = np.random.default_rng(1)
    lattice = random_lattice(rng, scores=scores)
    rays = random_rays(rng, lattice[2])
    depth, opacity, probs = composite_baked_rays(lattice, rays, 0.07, scores, min_trans)
    for r in range(len(depth)):
        want = naive_ray(lattice, tuple(a[r] for a in rays), 0.07, scores, min_trans)
        assert depth[r] == pytest.approx(want[0], abs=1e-9)
        assert opacity[r] == pytest.approx(want[1], abs=1e-9)
        np.testing.assert_allclose(probs[r], want[2], atol=1e-9)
    np.testing.assert_allclose(probs.sum(-1), 1.0, atol=1e-12)


def test_rays_match_the_renderers_maths():
    """Same samples through scenelabel.render.volume (weights, depth, eq. 7) in float64: the kernel
    composites as the field's renderer does, up to its early stop (the renderer's eq. 7 takes
    logits: the log of the lattice's normalised probabilities)."""
    rng = np.random.default_rng(2)
    lattice = random_lattice(rng, scores=False)
    density, class_values, corner, spacing = lattice
    o, d, t_min, t_max = random_rays(rng, corner, n=30)
    step = 0.05
    depth, opacity, probs = composite_baked_rays(lattice, (o, d, t_min, t_max), step, min_trans=0.0)
    n_samples = int(np.ceil((t_max - t_min).max() / step)) + 1
    ends = np.minimum(t_min[:, None] + step * np.arange(1, n_samples + 1), t_max[:, None])
    starts = np.concatenate([t_min[:, None], ends[:, :-1]], -1)
    mids = 0.5 * (starts + ends)
    points = (o[:, None] + mids[..., None] * d[:, None]).reshape(-1, 3)
    sigmas = torch.as_tensor(trilinear(density[..., None], corner, spacing, points).astype(np.float64)).reshape(len(o), -1)
    p = torch.as_tensor(trilinear(class_values, corner, spacing, points).astype(np.float64)).reshape(len(o), n_samples, -1)
    logits = (p / p.sum(-1, keepdim=True).clamp(min=1e-300)).clamp(min=1e-300).log()  # outside (no weight): all equal
    weights, _, _ = weights_from_density(sigmas.clamp(min=0), torch.as_tensor(ends - starts))
    want_depth = depth_from_weights(weights, torch.as_tensor(mids), torch.as_tensor(t_min), torch.as_tensor(t_max))
    np.testing.assert_allclose(opacity, weights.sum(-1).numpy(), atol=1e-6)
    np.testing.assert_allclose(depth, want_depth.numpy(), atol=1e-5)
    np.testing.assert_allclose(probs, class_probs_from_weights(weights, logits).numpy(), atol=1e-5)


@pytest.mark.parametrize("sigma", [0.0, 1e-30, 1e-8, 1.0, 1e8, 1e30, 3e38])
@pytest.mark.parametrize("n_classes", [1, 2, 150])
@pytest.mark.parametrize("scores", [False, True])
def test_rays_finite_at_extremes(sigma, n_classes, scores):
    shape = (3, 3, 3)
    density = np.full(shape, sigma, np.float32)
    if scores:
        class_values = np.broadcast_to(np.linspace(-1e4, 1e4, n_classes, dtype=np.float32), (*shape, n_classes))  # huge logits
    else:
        class_values = np.zeros((*shape, n_classes), np.uint8)
        class_values[..., -1] = 255  # certain of the last class, probability exactly 0 for the others
    o = np.array([[0.0, 0.5, 0.5], [0.5, 0.5, 0.5], [0.5, 0.0, 0.0], [5.0, 5.0, 5.0]])
    d = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.6, 0.8], [1.0, 0.0, 0.0]])  # zero components
    t_min = np.array([0.0, 0.0, 0.0, 0.0])
    t_max = np.array([1.0, 0.5, 1.0, -1.0])  # the last ray has nothing to march
    depth, opacity, probs = composite_baked_rays((density, class_values, np.zeros(3), 0.5), (o, d, t_min, t_max), 0.1, scores)
    assert np.all(np.isfinite(depth)) and np.all(np.isfinite(opacity)) and np.all(np.isfinite(probs))
    assert np.all((opacity >= 0) & (opacity <= 1))
    np.testing.assert_allclose(probs.sum(-1), 1.0, atol=1e-9)
    assert opacity[3] == 0 and depth[3] == 0.0  # empty interval: nothing, depth max(t_max, 0)
    if sigma >= 1e8:  # opaque at once: all weight in the first sample, depth its middle
        np.testing.assert_allclose(opacity[:3], 1.0)
        np.testing.assert_allclose(depth[:3], 0.05)
        assert np.all(probs[:3].argmax(-1) == n_classes - 1)
    if sigma <= 1e-30:  # empty: the far end and the uniform law
        np.testing.assert_allclose(depth[:3], t_max[:3])
        np.testing.assert_allclose(probs, 1.0 / n_classes)


@pytest.mark.parametrize("spacing", [1e-6, 1.0, 1e6])
def test_points_at_any_scale(spacing):
    """The same lattice at micrometre to megametre spacing gives the same values at the same
    relative positions."""
    rng = np.random.default_rng(3)
    values = random_lattice(rng)[1]
    corner = np.array([3.0, -2.0, 1.0]) * spacing
    rel = rng.uniform(0, 1, (50, 3)) * (np.array(values.shape[:3]) - 1)
    got = trilinear(values, corner, spacing, corner + rel * spacing)
    want = trilinear(values, np.zeros(3), 1.0, rel)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4)


def _lattice(v):
    return (v[..., 0], v[..., 1:], np.zeros(3), 1.0)


_RAY = (np.zeros((1, 3)),) * 2 + (np.zeros(1), np.ones(1))


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda v: trilinear(v[..., 0], np.zeros(3), 1.0, np.zeros((1, 3))), "values must be"),
        (lambda v: trilinear(v, np.zeros(3), 0.0, np.zeros((1, 3))), "spacing"),
        (lambda v: composite_baked_rays((v[..., 0], np.zeros((2, 2, 3, 2)), np.zeros(3), 1.0), _RAY, 0.1), "differ in vertices"),
        (lambda v: composite_baked_rays((v, v, np.zeros(3), 1.0), _RAY, 0.1), "density must be"),
        (lambda v: composite_baked_rays(_lattice(v), (np.zeros((2, 3)),) * 2 + (np.zeros(2), np.ones(3)), 0.1), "rays must"),
        (lambda v: composite_baked_rays(_lattice(v), _RAY, -1.0), "step"),
        (lambda v: composite_baked_rays(_lattice(v), _RAY, 0.1, min_trans=1.0), "min_trans"),
    ],
)
def test_bad_kernel_inputs(call, match):
    with pytest.raises(InputError, match=match):
        call(np.zeros((2, 2, 2, 3), np.float32))


# ---- a baked toy field (the session's toy build, tests/conftest.py)


@pytest.fixture(scope="module")
def fields(toy_build):
    """The toy field, baked at its default spacing (its finest cell) and at half of it."""
    field = SemanticField.load(toy_build.out_dir)
    return field, BakedField.from_field(field), BakedField.from_field(field, field.finest_cell() / 2)


def test_baked_points_answer_as_the_field(fields):
    field, baked, fine = fields
    pts = np.random.default_rng(4).uniform(field.aabb[0] - 0.1, field.aabb[1] + 0.1, (20000, 3))
    want = field.query_points(pts)
    got, got_fine = baked.query_points(pts), fine.query_points(pts)
    np.testing.assert_array_equal(got.class_ids, want.class_ids)
    outside = ~field._inside(pts)  # FREE where a training camera saw through, else UNKNOWN: as the field
    np.testing.assert_array_equal(got.label[outside], want.label[outside])
    assert set(got.label[outside].tolist()) == {FREE, UNKNOWN}
    agree, agree_fine = np.mean(got.label == want.label), np.mean(got_fine.label == want.label)
    assert agree > 0.9 and agree_fine > 0.97 and agree_fine >= agree  # a finer lattice follows the field closer
    np.testing.assert_allclose(got.probs.sum(-1)[field._inside(pts)], 1.0, atol=1e-9)
    # at the lattice's vertices the field's own values come back (float32 density, uint8 probabilities)
    vertices = baked.corner + baked.voxel_size * np.array([[3, 4, 2], [10, 7, 5], [0, 0, 0]])
    at = baked.query_points(vertices), field.query_points(vertices)
    np.testing.assert_allclose(at[0].density, at[1].density, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(at[0].probs, at[1].probs, atol=1 / 255)


def test_baked_rays_answer_as_the_field(fields):
    field, baked, fine = fields
    rng = np.random.default_rng(5)
    n = 3000
    centre = 0.5 * (field.aabb[0] + field.aabb[1])
    origins = centre + rng.uniform(-0.3, 0.3, (n, 3))
    directions = rng.normal(size=(n, 3))
    want = field.query_rays(origins, directions, with_rgb=False)
    for lattice, share in ((baked, 0.9), (fine, 0.96)):
        got = lattice.query_rays(origins, directions * 7.0)  # length does not matter
        assert np.mean(got.label == want.label) > share
        hit = (got.label >= 0) & (want.label >= 0)
        assert np.median(np.abs(got.depth[hit] - want.depth[hit])) < lattice.voxel_size
        # the ray contract: finite depth exactly where the ray hits, for both
        for answer in (got, want):
            np.testing.assert_array_equal(np.isfinite(answer.depth), answer.label >= 0)
    got = baked.query_rays(origins, directions)
    np.testing.assert_allclose(got.probs.sum(-1), 1.0, atol=1e-9)
    # near / far limit the depth; a ray that never enters the bounds is UNKNOWN
    limited = baked.query_rays(origins[:50], directions[:50], near=0.01, far=0.02)
    hit = limited.label >= 0
    assert np.all((limited.depth[hit] >= 0.01 - 1e-12) & (limited.depth[hit] <= 0.02 + 1e-12))
    assert np.all((limited.depth[~hit] == np.inf) & (limited.label[~hit] == FREE))
    outside = baked.query_rays(field.aabb[1] + 1.0, np.ones((1, 3)))
    assert outside.label[0] == UNKNOWN and outside.depth[0] == np.inf
    sky = baked.query_rays(centre[None], np.array([[0.0, 0.0, 1.0]]), far=1e-6)
    assert sky.label[0] == FREE


def test_baked_concurrent_queries_match_sequential(fields):
    _, baked, _ = fields
    pts = np.random.default_rng(6).uniform(baked.aabb[0], baked.aabb[1], (4, 30000, 3))
    assert_concurrent_calls_match(lambda p: baked.query_points(p).density, pts)
    rays = np.random.default_rng(7).normal(size=(4, 20000, 3))
    assert_concurrent_calls_match(lambda d: baked.query_rays(np.zeros_like(d), d).depth, rays)


def test_bake_refuses_what_it_cannot_hold(fields):
    field, baked, _ = fields
    with pytest.raises(InputError, match="voxel_size"):
        BakedField.from_field(field, 0.0)
    extent = float(np.prod(field.aabb[1] - field.aabb[0]))
    tiny = (extent * (1 + field.class_map.num_classes) * 4 / MAX_BAKE_BYTES) ** (1 / 3) / 2
    with pytest.raises(InputError, match="larger voxel size"):
        BakedField.from_field(field, tiny)
    assert not baked.density.flags.writeable and not baked.class_values.flags.writeable
    with pytest.raises(InputError, match="directions"):
        baked.query_rays(np.zeros((1, 3)), np.zeros((1, 3)))


@pytest.mark.parametrize("scores", [True, False])
def test_saved_baked_field_answers_the_same(tmp_path, scores):
    """BakedField.save / load: the same lattice, attributes and answers; a second save needs
    overwrite; a zarr that is not a baked field is refused."""
    rng = np.random.default_rng(11)
    density, class_values, corner, spacing = random_lattice(rng, (9, 7, 8), 3, scores)
    aabb = np.stack([corner, corner + spacing * (np.array(density.shape) - 1)])
    baked = BakedField((density, class_values, corner, spacing), aabb, {4: "floor", 2: "chair", 9: "wall"}, (0.05, 0.02, scores))
    path = baked.save(tmp_path / "baked.zarr")
    loaded = BakedField.load(path)
    np.testing.assert_array_equal(loaded.density, baked.density)
    np.testing.assert_array_equal(loaded.class_values, baked.class_values)
    assert loaded.class_values.dtype == baked.class_values.dtype
    assert loaded.classes == baked.classes and list(loaded.class_ids) == [4, 2, 9]  # channel order kept
    assert (loaded.voxel_size, loaded.occupancy_delta, loaded.step, loaded.scores) == (spacing, 0.05, 0.02, scores)
    np.testing.assert_array_equal(loaded.aabb, baked.aabb)
    o, d, _, _ = random_rays(rng, corner, 200)
    for a, b in ((baked.query_rays(o, d), loaded.query_rays(o, d)), (baked.query_points(o), loaded.query_points(o))):
        np.testing.assert_array_equal(a.label, b.label)
        np.testing.assert_array_equal(a.probs, b.probs)
    with pytest.raises(InputError, match="already exists"):
        baked.save(path)
    baked.save(path, overwrite=True)
    with pytest.raises(InputError, match="not a zarr group"):
        BakedField.load(tmp_path)
    import zarr

    zarr.open_group(str(tmp_path / "other.zarr"), mode="w").attrs["format"] = "something.else"
    with pytest.raises(InputError, match="expected 'scenelabel.baked_field'"):
        BakedField.load(tmp_path / "other.zarr")


def test_a_saved_baked_field_keeps_the_training_cameras(fields, tmp_path):
    """Outside the bounds a loaded BakedField answers FREE where the field's training cameras saw
    through, as before saving; cameras with unknown near / far (NaN) survive the zarr attributes."""
    field, baked, _ = fields
    loaded = BakedField.load(baked.save(tmp_path / "toy.zarr"))
    np.testing.assert_array_equal(loaded.train_cameras.c2w, field.training_cameras().c2w)
    pts = np.random.default_rng(5).uniform(field.aabb[0] - 1.0, field.aabb[1] + 1.0, (5000, 3))
    np.testing.assert_array_equal(loaded.query_points(pts).label, baked.query_points(pts).label)
    cams = field.training_cameras()
    cams.near[:], cams.far[:] = np.nan, np.nan
    unknown_limits = BakedField((baked.density, baked.class_values, baked.corner, baked.voxel_size), baked.aabb,
                                baked.classes, (baked.occupancy_delta, baked.step, baked.scores), cams)
    again = BakedField.load(unknown_limits.save(tmp_path / "nan.zarr"))
    assert np.all(np.isnan(again.train_cameras.near)) and np.all(np.isnan(again.train_cameras.far))
    np.testing.assert_array_equal(again.query_points(pts).label, unknown_limits.query_points(pts).label)


def test_a_saved_baked_field_answers_without_torch(tmp_path):
    """A planner's process: load a saved BakedField and cast rays with torch unimportable."""
    rng = np.random.default_rng(12)
    density, class_values, corner, spacing = random_lattice(rng, (6, 6, 6), 2, False)
    aabb = np.stack([corner, corner + spacing * 5])
    path = BakedField((density, class_values, corner, spacing), aabb, {0: "a", 1: "b"}, (0.05, 0.02, False)).save(tmp_path / "b.zarr")
    code = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in ('torch', 'cv2'):\n"
        "            raise ImportError(name + ' blocked')\n"
        "sys.meta_path.insert(0, Block())\n"
        "import numpy as np\n"
        "from scenelabel import BakedField\n"
        f"baked = BakedField.load({str(path)!r})\n"
        f"r = baked.query_rays(np.full((5, 3), {corner.tolist()!r}) - 0.1, np.ones((5, 3)))\n"
        "print(sorted(set(r.label.tolist())), 'torch' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out[-1] == "False"
