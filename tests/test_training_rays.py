"""scenelabel.train.rays: the training views' rays with their pixel footprints, and rays moved
within their pixels (train.pixel_jitter) against rays cast through those image points."""

import numpy as np
import pytest
import torch

from scenelabel import load_scene, preset, write_toy_scene
from scenelabel.config import TrainConfig
from scenelabel.data.scene import ClassMap
from scenelabel.errors import ConfigError
from scenelabel.geometry.cameras import Cameras
from scenelabel.geometry.frame import SceneFrame
from scenelabel.geometry.rays import pixel_grid, rays_from_cameras
from scenelabel.train.pipeline import prepare_training
from scenelabel.train.rays import jittered_rays, rays_for_views


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return write_toy_scene(tmp_path_factory.mktemp("rays") / "scene", n_train=7, n_test=1, width=32, height=24)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = a / np.linalg.norm(a, axis=-1, keepdims=True), b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.arccos(np.clip((a * b).sum(-1), -1.0, 1.0))


@pytest.mark.parametrize("distortion", [None, (0.08, -0.02, 0.0, 0.0)], ids=["pinhole", "radial"])
def test_jittered_rays_pass_through_the_drawn_point_of_the_pixel(distortion):
    """A ray moved by (u, v) pixels goes through that image point, as rays_from_cameras casts it, to
    within a small fraction of a pixel's angle (the step is linear across the pixel); offset 0 is the
    centre ray itself; the box's entry and exit are those of the moved ray."""
    c2w = np.eye(4)
    c2w[:3, 3] = [0.1, -0.2, -3.0]
    kwargs = {} if distortion is None else {"distortion": np.array([distortion])}
    cameras = Cameras.create(c2w[None], 40.0, 42.0, 16.0, 12.0, 32, 24, **kwargs)
    centres = pixel_grid(32, 24)
    origins, directions = rays_from_cameras(cameras, 0)
    steps = [rays_from_cameras(cameras, 0, centres + np.array(step))[1] - directions for step in ((1.0, 0.0), (0.0, 1.0))]
    offsets = np.random.default_rng(0).uniform(-0.5, 0.5, (len(centres), 2))
    offsets[:4] = [[0.0, 0.0], [0.5, 0.5], [-0.5, -0.5], [0.5, -0.5]]
    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    t = lambda x: torch.as_tensor(x, dtype=torch.float32)  # noqa: E731
    moved, t_enter, t_exit = jittered_rays(t(origins), t(directions), t(steps[0]), t(steps[1]), t(offsets), aabb)
    exact = rays_from_cameras(cameras, 0, centres + offsets)[1]
    pixel_angle = 1.0 / 40.0
    assert _angle(moved.numpy(), exact).max() < 0.02 * pixel_angle
    np.testing.assert_allclose(moved[0].numpy(), directions[0], atol=1e-6)
    np.testing.assert_allclose(moved.norm(dim=-1).numpy(), 1.0, atol=1e-6)
    hits = t_exit > t_enter
    inside = t(origins)[hits] + moved[hits] * ((t_enter[hits] + t_exit[hits]) / 2)[:, None]
    assert hits.any() and bool((inside.abs() <= 1.0 + 1e-5).all())
    for tt in (t_enter[hits], t_exit[hits]):  # entry and exit lie on the box's faces
        face = (t(origins)[hits] + moved[hits] * tt[:, None]).abs().max(-1).values
        np.testing.assert_allclose(face.numpy(), 1.0, atol=1e-4)


def test_footprints_are_the_next_pixels_directions_and_only_when_asked(toy):
    scene = load_scene(toy)
    frame = SceneFrame.from_aabb(scene.aabb)
    class_map = ClassMap.from_labels(scene.labels, scene.classes, scene.ignore_index)
    aabb_n = torch.as_tensor(frame.to_normalised(scene.aabb), dtype=torch.float32)
    plain = rays_for_views(scene, [0, 1], frame, class_map, aabb_n)
    rays = rays_for_views(scene, [0, 1], frame, class_map, aabb_n, footprint=True)
    assert plain.pixel_dx is None and plain.pixel_dy is None
    torch.testing.assert_close(rays.directions, plain.directions)
    centres = pixel_grid(int(scene.cameras.width[1]), int(scene.cameras.height[1]))
    n0 = int(scene.cameras.width[0] * scene.cameras.height[0])
    right = rays_from_cameras(scene.cameras, 1, centres + [1.0, 0.0])[1] - rays_from_cameras(scene.cameras, 1)[1]
    np.testing.assert_allclose(rays.pixel_dx[n0:].numpy(), right, atol=1e-6)
    below = rays_from_cameras(scene.cameras, 0, pixel_grid(32, 24) + [0.0, 1.0])[1] - rays_from_cameras(scene.cameras, 0)[1]
    np.testing.assert_allclose(rays.pixel_dy[:n0].numpy(), below, atol=1e-6)


def test_pixel_jitter_trains_on_moved_rays(toy):
    """With train.pixel_jitter the trainer holds the footprints and its steps stay finite; a config
    without it holds none (and its rays are drawn as before)."""
    for jitter in (False, True):
        config = preset("quick", {"train": {"steps": 10, "pixel_jitter": jitter}})
        trainer, _, _ = prepare_training(load_scene(toy), config, torch.device("cpu"))
        assert (trainer.rays.pixel_dx is not None) == jitter
        logs = [trainer.train_step() for _ in range(10)]
        assert all(np.isfinite(log["loss"]) for log in logs)
    with pytest.raises(ConfigError, match="train.pixel_jitter must be true or false"):
        TrainConfig(pixel_jitter="yes")
