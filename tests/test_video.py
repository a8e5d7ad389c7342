"""Video in (scenelabel.data.video): sharpness, the frame choice, frames_from_video and its cache,
the load_scene dispatch and `scenelabel build clip.mp4`, on tiny clips of a synthetic room
(scenelabel.data.suite_video.write_room_video: known poses, known blurred frames)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

from scenelabel import load_scene
from scenelabel.data import video as video_module
from scenelabel.data.suite_video import motion_blur, read_video_truth, write_room_video
from scenelabel.data.video import (
    VIDEO_FILE,
    blurred_frames,
    choose_frames,
    frame_name,
    frame_sharpness,
    frames_from_video,
    laplacian_variance,
    prepare_video_scene,
    target_frame_count,
    window_edges,
)
from scenelabel.errors import InputError
from scenelabel.metrics import pose_rotation_errors_deg

TINY = dict(seconds=2.0, fps=10.0, width=96, height=72)  # 20 frames: frame choice only, no SfM
SFM_CLIP = dict(seconds=3.0, fps=6.0, width=320, height=240)  # 18 frames, 9 chosen: SfM in ~2 s
# (at 240x180 SfM's focal length comes out ~15% off and rotations ~2 degrees)


def _textured(seed: int = 0, size=(120, 160)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    grey = ndimage.gaussian_filter(rng.random(size), 1.0)
    grey = (grey - grey.min()) / (grey.max() - grey.min())
    return np.repeat((grey * 255).astype(np.uint8)[..., None], 3, axis=2)


# --------------------------------------------------------------------------------------------
# pure functions


def test_sharpness_orders_a_sharp_frame_above_its_blurred_copies():
    sharp = _textured()
    assert frame_sharpness(sharp) > 4 * frame_sharpness(cv2.GaussianBlur(sharp, (0, 0), 2.0))
    assert frame_sharpness(sharp) > 2 * frame_sharpness(motion_blur(sharp, 7, 30.0))
    assert laplacian_variance(np.full((10, 12), 77.0)) == 0.0


def test_sharpness_is_measured_at_most_sharpness_size_wide():
    big = _textured(1, (480, 640))
    small = cv2.resize(cv2.cvtColor(big, cv2.COLOR_BGR2GRAY), (320, 240), interpolation=cv2.INTER_AREA)
    assert frame_sharpness(big, size=320) == pytest.approx(laplacian_variance(small))
    assert frame_sharpness(big, size=1000) == pytest.approx(laplacian_variance(cv2.cvtColor(big, cv2.COLOR_BGR2GRAY)))


def test_blurred_frames_are_those_far_below_their_neighbours():
    s = np.array([10, 11, 2, 10, 12, 3, 11, 10, 9, 10.0])
    np.testing.assert_array_equal(np.flatnonzero(blurred_frames(s, radius=2, ratio=0.5)), [2, 5])
    # a slow change of content is not blur: a steady fall by 10% a frame flags nothing
    assert not blurred_frames(100 * 0.9 ** np.arange(30), radius=3, ratio=0.5).any()


def test_window_choice_keeps_the_sharpest_unblurred_frame_per_window():
    s = np.array([5, 9, 6, 20, 1, 8, 7, 8, 1, 1, 9, 10.0])
    #             [ window 0 ][  window 1  ][ window 2  ]  (4 frames each)
    chosen, blurred = choose_frames(s, n_windows=3, radius=2, ratio=0.5)
    assert blurred[4] and blurred[8] and blurred[9]
    np.testing.assert_array_equal(chosen, [3, 5, 11])  # 20 in window 0; 8 (first of the sharpest) in 1
    # every frame of the middle window blurred: that window gives none
    s2 = np.array([10, 10, 10, 1, 1, 1, 10, 10, 10.0])
    chosen, blurred = choose_frames(s2, n_windows=3, radius=3, ratio=0.5)
    assert blurred[3:6].all() and not blurred[[0, 1, 2, 6, 7, 8]].any()
    assert len(chosen) == 2 and chosen[0] < 3 and chosen[1] >= 6


def test_window_edges_and_target_count():
    np.testing.assert_array_equal(window_edges(10, 3), [0, 3, 7, 10])
    np.testing.assert_array_equal(window_edges(4, 9), [0, 1, 2, 3, 4])  # at most one window per frame
    assert target_frame_count(60, 10.0, 3.0, 150) == 18  # 6 s x 3 per second
    assert target_frame_count(900, 30.0, 3.0, 40) == 40  # capped
    assert target_frame_count(5, 30.0, 3.0, 150) == 2  # at least 2
    assert target_frame_count(3, 1.0, 10.0, 150) == 3  # never more than the frames


# --------------------------------------------------------------------------------------------
# frames_from_video on a tiny clip


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny_video")
    return write_room_video(root / "clip.mp4", **TINY, seed=0)


def _fresh(clip, tmp_path: Path) -> Path:
    """A copy of the tiny clip (and its labels) in tmp_path, so tests do not share caches."""
    shutil.copy2(clip.video, tmp_path / "clip.mp4")
    shutil.copytree(clip.scene_dir, tmp_path / "clip")
    return tmp_path / "clip.mp4"


def test_synthetic_clip_has_frames_labels_and_truth(tiny_clip):
    capture = cv2.VideoCapture(str(tiny_clip.video))
    assert capture.get(cv2.CAP_PROP_FPS) == pytest.approx(TINY["fps"])
    frames = 0
    while capture.read()[0]:
        frames += 1
    assert frames == 20
    labels = sorted(p.name for p in (tiny_clip.scene_dir / "labels").iterdir())
    assert labels == [f"frame_{i:06d}.png" for i in range(20)]
    classes = json.loads((tiny_clip.scene_dir / "classes.json").read_text())
    ids = {c["id"] for c in classes["classes"]}
    label = np.array(Image.open(tiny_clip.scene_dir / "labels" / labels[0]))
    assert label.shape == (72, 96) and set(np.unique(label)) <= ids  # cameras inside the room: every ray hits
    poses, blurred = read_video_truth(tiny_clip.truth_path)
    assert sorted(poses) == list(range(20)) and blurred == set(tiny_clip.blurred) and len(blurred) == 3
    np.testing.assert_allclose(poses[5], tiny_clip.c2w[5])
    step = np.linalg.norm(np.diff(tiny_clip.c2w[:, :3, 3], axis=0), axis=1)
    assert step.max() < 0.06  # a smooth walk: a few cm per frame at 10 fps


def test_frames_from_video_writes_the_sharp_frames_by_source_index(tiny_clip, tmp_path):
    video = _fresh(tiny_clip, tmp_path)
    frames = frames_from_video(video, tmp_path / "clip")
    assert not frames.cached and frames.n_decoded == 20 and (frames.width, frames.height) == (96, 72)
    assert frames.fps == pytest.approx(10.0) and frames.n_windows == 6  # 2 s x 3 per second
    assert set(frames.blurred) == set(tiny_clip.blurred)  # every blurred frame found, no other
    assert not set(frames.indices) & set(tiny_clip.blurred)
    assert len(frames.indices) == 6 and list(frames.indices) == sorted(frames.indices)
    assert list(frames.names) == [frame_name(i) for i in frames.indices]
    written = sorted(p.name for p in (tmp_path / "clip" / "images").iterdir())
    assert written == list(frames.names)
    image = np.array(Image.open(tmp_path / "clip" / "images" / frames.names[0]))
    assert image.shape == (72, 96, 3)
    record = json.loads((tmp_path / "clip" / VIDEO_FILE).read_text())
    assert record["complete"] and record["source"] == "../clip.mp4" and record["indices"] == list(frames.indices)
    assert record["size"] == video.stat().st_size and record["mtime_ns"] == video.stat().st_mtime_ns


def test_the_cache_is_reused_and_invalidated_when_the_video_changes(tiny_clip, tmp_path, monkeypatch):
    video = _fresh(tiny_clip, tmp_path)
    scene = tmp_path / "clip"
    first = frames_from_video(video, scene)
    stamps = {p.name: p.stat().st_mtime_ns for p in (scene / "images").iterdir()}
    (scene / "sparse" / "0").mkdir(parents=True)  # stand-ins for the SfM cache of these frames
    (scene / "sparse" / "0" / "cameras.bin").write_bytes(b"x")
    (scene / "sfm").mkdir()

    def no_decoding(*args, **kwargs):
        raise AssertionError("decoded again")

    with monkeypatch.context() as patch:
        patch.setattr(video_module, "_score_frames", no_decoding)
        again = frames_from_video(video, scene)
        also = prepare_video_scene(scene)  # the folder: the video its video.json records
    assert again.cached and also.cached and again.indices == first.indices == also.indices
    assert {p.name: p.stat().st_mtime_ns for p in (scene / "images").iterdir()} == stamps
    assert (scene / "sparse" / "0" / "cameras.bin").is_file()

    # other parameters: extracted again (and the SfM cache of the old frames dropped)
    more = frames_from_video(video, scene, frames_per_second=5.0)
    assert not more.cached and len(more.indices) == 10
    assert not (scene / "sparse").exists() and not (scene / "sfm").exists()
    assert sorted(p.name for p in (scene / "images").iterdir()) == list(more.names)

    # a changed video: extracted again, even asked for nothing in particular
    (scene / "sfm").mkdir()
    write_room_video(video, seconds=3.0, fps=10.0, width=96, height=72, seed=1)
    changed = frames_from_video(video, scene)
    assert not changed.cached and changed.n_decoded == 30 and len(changed.indices) >= 8
    assert not (scene / "sfm").exists()
    assert sorted(p.name for p in (scene / "images").iterdir()) == list(changed.names)
    record = json.loads((scene / VIDEO_FILE).read_text())
    assert record["n_decoded"] == 30 and record["frames_per_second"] == 5.0  # None: the earlier choice
    assert len(changed.indices) >= 12


def test_a_folder_with_one_video_is_its_scene(tiny_clip, tmp_path):
    folder = tmp_path / "walk"
    folder.mkdir()
    shutil.copy2(tiny_clip.video, folder / "room.MOV")  # any case of a video suffix
    frames = prepare_video_scene(folder)
    assert frames.scene_dir == folder and (folder / "images" / frames.names[0]).is_file()
    assert json.loads((folder / VIDEO_FILE).read_text())["source"] == "room.MOV"
    shutil.copy2(tiny_clip.video, folder / "other.mp4")
    assert prepare_video_scene(folder).cached  # video.json says which video is the scene's
    (folder / VIDEO_FILE).unlink()
    shutil.rmtree(folder / "images")
    with pytest.raises(InputError, match="2 videos in the folder"):
        prepare_video_scene(folder)


@pytest.mark.parametrize("content", [b"", b"this is not a video\n" * 50])
def test_an_unreadable_video_is_an_input_error(tmp_path, content):
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(content)
    with pytest.raises(InputError, match="cannot read the video") as info:
        frames_from_video(bad, tmp_path / "bad")
    assert "\n" not in str(info.value) and str(bad) in str(info.value)
    with pytest.raises(InputError, match="cannot read the video"):
        load_scene(bad)


def test_images_not_from_the_video_are_never_overwritten(tiny_clip, tmp_path):
    video = _fresh(tiny_clip, tmp_path)
    photos = tmp_path / "clip" / "images"
    photos.mkdir()
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(photos / "mine.png")
    with pytest.raises(InputError, match="not extracted from a video"):
        frames_from_video(video, tmp_path / "clip")
    assert sorted(p.name for p in photos.iterdir()) == ["mine.png"]


def test_bad_parameters(tiny_clip, tmp_path):
    with pytest.raises(InputError, match="video not found"):
        frames_from_video(tmp_path / "missing.mp4", tmp_path / "x")
    for kwargs, field in (({"frames_per_second": 0}, "frames_per_second"), ({"max_frames": 1}, "max_frames")):
        with pytest.raises(InputError, match=field):
            frames_from_video(tiny_clip.video, tmp_path / "x", **kwargs)


def test_a_folder_of_photos_beside_a_video_uses_the_photos(tiny_clip, tmp_path, monkeypatch):
    folder = tmp_path / "both"
    (folder / "images").mkdir(parents=True)
    shutil.copy2(tiny_clip.video, folder / "clip.mp4")
    for i in range(2):
        Image.fromarray(_textured(i, (72, 96))).save(folder / "images" / f"{i}.png")
    called = {}

    def fake_run_sfm(scene_dir, *args, **kwargs):
        called["scene_dir"] = Path(scene_dir)
        raise InputError("stop here")

    monkeypatch.setattr("scenelabel.data.sfm.run_sfm", fake_run_sfm)
    with pytest.raises(InputError, match="stop here"):
        load_scene(folder)
    assert called["scene_dir"] == folder and not (folder / VIDEO_FILE).exists()


# --------------------------------------------------------------------------------------------
# end to end: a textured clip, structure from motion, load_scene and the CLI


@pytest.fixture(scope="module")
def sfm_clip(tmp_path_factory):
    root = tmp_path_factory.mktemp("sfm_video")
    return write_room_video(root / "clip.mp4", **SFM_CLIP, seed=0)


def test_load_scene_of_a_video_recovers_the_poses(sfm_clip):
    scene = load_scene(sfm_clip.video)
    record = json.loads((sfm_clip.scene_dir / VIDEO_FILE).read_text())
    assert scene.root == sfm_clip.scene_dir
    assert scene.names == [Path(n).stem for n in record["names"]]  # every chosen frame registered
    assert len(scene.names) >= 8 and not set(record["indices"]) & set(sfm_clip.blurred)
    assert scene.info["video"]["chosen"] == len(scene.names) and scene.info["video"]["decoded"] == 18
    assert all(label is not None for label in scene.labels)  # labels/frame_NNNNNN.png of the chosen frames
    truth, _ = read_video_truth(sfm_clip.truth_path)
    true = np.stack([truth[i] for i in record["indices"]])
    errors = pose_rotation_errors_deg(true, scene.cameras.c2w)
    assert errors.max() < 1.0, errors
    report = json.loads((sfm_clip.scene_dir / "sfm" / "report.json").read_text())
    assert report["matcher"] == "sequential"

    # the folder loads the same frames and the cached model (no decoding, no SfM)
    model = sfm_clip.scene_dir / "sparse" / "0" / "images.bin"
    stamp = model.stat().st_mtime_ns
    again = load_scene(sfm_clip.scene_dir)
    assert again.names == scene.names and model.stat().st_mtime_ns == stamp
    np.testing.assert_allclose(again.cameras.c2w, scene.cameras.c2w)


def test_cli_builds_a_video(sfm_clip, tmp_path):
    load_scene(sfm_clip.video)  # frames and SfM cached (shared with the test above)
    out = tmp_path / "out"
    args = ["build", str(sfm_clip.video), "--preset", "quick", "--steps", "2", "--downscale", "4", "--voxel-size", "8"]
    args += ["--out", str(out)]
    proc = subprocess.run(
        [sys.executable, "-m", "scenelabel", *args],  # 80x60 views and a coarse map (SfM units): a quick build
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])},
    )
    assert proc.returncode == 0, proc.stderr
    assert "video: chose" in proc.stderr and "(cached)" in proc.stderr and "sfm: registered" in proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 2 and metrics["n_test_views"] >= 1 and "miou" in metrics


def test_config_values_and_output_folders(tiny_clip, tmp_path):
    from scenelabel.config import config_from_dict
    from scenelabel.errors import ConfigError
    from scenelabel.train.batch import out_dirs_for

    assert config_from_dict({"data": {"video_frames_per_second": 2, "video_max_frames": 40}}).data.video_max_frames == 40
    for key, value in (("video_frames_per_second", 0), ("video_max_frames", 1), ("video_max_frames", 2.5)):
        with pytest.raises(ConfigError, match=f"data.{key}"):
            config_from_dict({"data": {key: value}})
    # several videos built at once: each one's output in its scene folder, or OUT/<scene folder name>
    assert out_dirs_for([tiny_clip.video]) == [tiny_clip.scene_dir / "scenelabel"]
    assert out_dirs_for([tiny_clip.video], tmp_path) == [tmp_path / "clip"]
