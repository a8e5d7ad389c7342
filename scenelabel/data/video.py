"""Video in: sample sharp frames of a clip into a scene folder, cached like photos.

``frames_from_video(video, scene_dir)`` decodes the clip with OpenCV twice: the first pass scores
every frame's sharpness, the second writes the chosen ones to ``scene_dir/images/``. Choice (pure
functions below, tested on their own):

1. **Sharpness** of a frame (:func:`frame_sharpness`): the variance of the Laplacian of the grey
   frame shrunk (area-averaged) to at most :data:`SHARPNESS_SIZE` pixels on its longer side, so
   that scores do not depend on the video's resolution and sensor noise counts less.
2. **Blurred frames** (:func:`blurred_frames`): a frame whose sharpness is below
   ``blur_ratio`` (:data:`BLUR_RATIO`) times the median sharpness of the frames within
   :data:`NEIGHBOUR_SECONDS` of it (itself included): motion blur, a focus hunt. Comparing with
   neighbours, not with one global threshold, keeps a clip whose content changes (a plain wall, a
   busy shelf) from losing whole stretches.
3. **Windows** (:func:`choose_frames`): the clip is cut into ``n`` runs of consecutive frames of
   (nearly) equal length, ``n = min(max_frames, ceil(duration * frames_per_second))``
   (:func:`target_frame_count`; defaults :data:`FRAMES_PER_SECOND`, :data:`MAX_FRAMES`), and
   the sharpest frame of each run that is not blurred is kept; a run whose frames are all
   blurred gives none.

Frames are written as ``images/frame_NNNNNN.jpg`` (JPEG quality :data:`JPEG_QUALITY`), ``NNNNNN``
the 0-based index of the frame in the video, so labels made per source frame
(``labels/frame_NNNNNN.png``) match whichever frames are chosen. ``scene_dir/video.json``
records the source (its path relative to the scene folder, size and modification time), the
parameters and the choice. A second call with the same video and parameters reuses the frames
without decoding (``VideoFrames.cached``); a changed video (size or modification time) or
changed parameters extract again, and then delete the frames written before and the structure
from motion cache (``sparse/0``, ``sfm/``) so that poses are recovered anew.

The scene folder of a video (:func:`prepare_video_scene`): ``clip/`` beside ``clip.mp4``, or the
folder that holds the video. Video suffixes: :data:`VIDEO_SUFFIXES`, any case.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from scenelabel._files import atomic_write_bytes
from scenelabel.errors import InputError

__all__ = [
    "VIDEO_SUFFIXES",
    "VIDEO_FILE",
    "FRAMES_PER_SECOND",
    "MAX_FRAMES",
    "BLUR_RATIO",
    "SHARPNESS_SIZE",
    "NEIGHBOUR_SECONDS",
    "VideoFrames",
    "is_video",
    "find_video",
    "video_scene_dir",
    "frame_name",
    "laplacian_variance",
    "frame_sharpness",
    "blurred_frames",
    "window_edges",
    "choose_frames",
    "target_frame_count",
    "frames_from_video",
    "prepare_video_scene",
    "read_video_record",
]

#: File suffixes read as videos (compared in lower case).
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v")
#: The record of an extraction, in the scene folder.
VIDEO_FILE = "video.json"
#: Default target of chosen frames per second of video.
FRAMES_PER_SECOND = 3.0
#: Default cap on the number of chosen frames (structure from motion and training time grow with it).
MAX_FRAMES = 150
#: A frame sharper than this fraction of its neighbours' median sharpness is not blurred.
BLUR_RATIO = 0.5
#: Longer side (pixels) of the grey frame whose Laplacian variance is the sharpness.
SHARPNESS_SIZE = 320
#: Neighbours of a frame for the blur test: the frames within this many seconds of it.
NEIGHBOUR_SECONDS = 0.5
#: Frame rate assumed when the container does not state one.
FALLBACK_FPS = 30.0
#: Quality of the written JPEG frames (OpenCV's 0-100).
JPEG_QUALITY = 95
IMAGES_FOLDER = "images"
_RECORD_VERSION = 1


@dataclass(frozen=True)
class VideoFrames:
    """What :func:`frames_from_video` chose from a video.

    Attributes:
        video: the source video.
        scene_dir: the folder holding ``images/`` and ``video.json``.
        indices: 0-based source frame indices chosen, ascending.
        names: their file names in ``images/`` (``frame_NNNNNN.jpg``).
        sharpness: sharpness (:func:`frame_sharpness`) of each chosen frame.
        blurred: source frame indices found blurred (:func:`blurred_frames`; never chosen).
        n_decoded: frames decoded from the video.
        n_windows: the target number of frames (:func:`target_frame_count`); windows left empty
            (all their frames blurred) are ``n_windows - len(indices)``.
        fps: the video's frame rate (:data:`FALLBACK_FPS` when the container does not say).
        width, height: frame size in pixels.
        frames_per_second, max_frames, blur_ratio: the parameters of the choice.
        seconds: wall time of the extraction (of the original one when ``cached``).
        cached: True when the frames were reused from an earlier extraction.
    """

    video: Path
    scene_dir: Path
    indices: tuple[int, ...]
    names: tuple[str, ...]
    sharpness: tuple[float, ...]
    blurred: tuple[int, ...]
    n_decoded: int
    n_windows: int
    fps: float
    width: int
    height: int
    frames_per_second: float
    max_frames: int
    blur_ratio: float
    seconds: float
    cached: bool = False

    def summary(self) -> str:
        """One line for logs and the CLI."""
        source = "cached" if self.cached else f"{self.seconds:.1f} s"
        empty = self.n_windows - len(self.indices)
        return (
            f"chose {len(self.indices)} of {self.n_decoded} frames ({self.width}x{self.height}, {self.fps:g} fps) "
            f"into {self.scene_dir / IMAGES_FOLDER}; {len(self.blurred)} blurred frames dropped"
            + (f", {empty} windows without a sharp frame" if empty else "")
            + f" ({source})"
        )


# --------------------------------------------------------------------------------------------
# files and folders


def is_video(path: str | Path) -> bool:
    """``path`` names a file with a video suffix (:data:`VIDEO_SUFFIXES`, any case)."""
    path = Path(path)
    return path.suffix.lower() in VIDEO_SUFFIXES and path.is_file()


def find_video(folder: str | Path) -> Path | None:
    """The one video directly in ``folder``, or None when there is none.

    Raises:
        InputError: several videos (which one is meant is unclear).
    """
    folder = Path(folder)
    videos = sorted(p for p in folder.iterdir() if is_video(p))
    if len(videos) > 1:
        names = ", ".join(p.name for p in videos[:4]) + (", ..." if len(videos) > 4 else "")
        raise InputError(f"{len(videos)} videos in the folder ({names}): pass the path of the one to build", folder)
    return videos[0] if videos else None


def video_scene_dir(video: str | Path) -> Path:
    """The scene folder of a video file: ``clip/`` beside ``clip.mp4``."""
    video = Path(video)
    return video.with_name(video.stem)


def frame_name(index: int) -> str:
    """Image file name of source frame ``index`` (0-based): ``frame_000123.jpg``."""
    return f"frame_{int(index):06d}.jpg"


# --------------------------------------------------------------------------------------------
# the choice (pure functions)


def laplacian_variance(grey: np.ndarray) -> float:
    """Variance of the 3x3 Laplacian (OpenCV ``ksize=1``, replicated borders) of a grey image.

    Args:
        grey: [h, w] grey levels (any real dtype; 0-255 for 8-bit frames).
    Returns:
        the variance, in squared grey levels; 0 for a flat image.
    """
    laplacian = cv2.Laplacian(np.asarray(grey, np.float64), cv2.CV_64F, ksize=1, borderType=cv2.BORDER_REPLICATE)
    return float(laplacian.var())


def frame_sharpness(frame: np.ndarray, size: int = SHARPNESS_SIZE) -> float:
    """Sharpness of a video frame: :func:`laplacian_variance` of its grey version, area-shrunk to
    at most ``size`` pixels on its longer side (never enlarged).

    Args:
        frame: [h, w, 3] uint8 (BGR or RGB: the grey weights differ slightly) or [h, w] grey.
        size: longer side of the scored image, pixels.
    Returns:
        the sharpness (larger: sharper).
    """
    frame = np.asarray(frame)
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame
    h, w = grey.shape
    factor = size / max(h, w)
    if factor < 1.0:
        grey = cv2.resize(grey, (max(1, round(w * factor)), max(1, round(h * factor))), interpolation=cv2.INTER_AREA)
    return laplacian_variance(grey)


def blurred_frames(sharpness: np.ndarray, radius: int, ratio: float = BLUR_RATIO) -> np.ndarray:
    """Frames much less sharp than their neighbours.

    Args:
        sharpness: [n] per-frame sharpness, in video order.
        radius: neighbours are the frames at most ``radius`` positions away (itself included;
            fewer at the ends).
        ratio: a frame is blurred when its sharpness is below ``ratio`` times its neighbours' median.
    Returns:
        [n] bool, True for a blurred frame.
    """
    s = np.asarray(sharpness, np.float64)
    radius = max(0, int(radius))
    medians = np.array([np.median(s[max(0, i - radius) : i + radius + 1]) for i in range(len(s))])
    return s < ratio * medians


def window_edges(n_frames: int, n_windows: int) -> np.ndarray:
    """[n_windows + 1] frame positions cutting ``n_frames`` frames into runs of nearly equal length.

    Run ``k`` is ``[edges[k], edges[k + 1])``; ``n_windows`` is clipped to ``[1, n_frames]``.
    """
    n_windows = min(max(1, int(n_windows)), max(1, int(n_frames)))
    return np.round(np.linspace(0, n_frames, n_windows + 1)).astype(np.int64)


def choose_frames(
    sharpness: np.ndarray, n_windows: int, radius: int, ratio: float = BLUR_RATIO
) -> tuple[np.ndarray, np.ndarray]:
    """The sharpest frame of each window that is not blurred.

    Args:
        sharpness: [n] per-frame sharpness, in video order.
        n_windows: number of windows of consecutive frames (:func:`window_edges`).
        radius, ratio: the blur test (:func:`blurred_frames`).
    Returns:
        chosen [k] int64 frame positions, ascending (k <= n_windows: a window whose frames are all
        blurred gives none); blurred [n] bool.
    """
    s = np.asarray(sharpness, np.float64)
    blurred = blurred_frames(s, radius, ratio)
    if len(s) == 0:
        return np.zeros(0, np.int64), blurred
    edges = window_edges(len(s), n_windows)
    chosen = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        candidates = np.flatnonzero(~blurred[lo:hi]) + lo
        if len(candidates):
            chosen.append(candidates[np.argmax(s[candidates])])
    return np.asarray(chosen, np.int64), blurred


def target_frame_count(n_frames: int, fps: float, frames_per_second: float, max_frames: int) -> int:
    """Number of windows (frames to choose): ``ceil(duration * frames_per_second)``, at least 2,
    at most ``max_frames`` and ``n_frames``; duration = ``n_frames / fps``."""
    wanted = math.ceil(n_frames / fps * frames_per_second - 1e-9)  # 1e-9: 6 s x 3 /s is 18, not 19
    return int(min(max_frames, n_frames, max(2, wanted)))


# --------------------------------------------------------------------------------------------
# decoding


def _open(video: Path) -> cv2.VideoCapture:
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        capture.release()
        raise InputError("cannot read the video: not a format OpenCV can decode (or not a video)", video)
    return capture


def _bar(total: int, desc: str, progress: bool):
    from tqdm import tqdm

    return tqdm(total=total or None, disable=not progress, unit="frame", desc=desc, dynamic_ncols=True, leave=False)


def _score_frames(video: Path, progress: bool) -> tuple[np.ndarray, float, int, int]:
    """First pass: (sharpness [n], fps, width, height) of every decodable frame."""
    capture = _open(video)
    try:
        fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
        stated = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        scores, size = [], None
        with _bar(stated, "video: scoring frames", progress) as bar:
            while True:
                ok, frame = capture.read()
                if not ok or frame is None:
                    break
                if size is None:
                    size = frame.shape[1], frame.shape[0]
                scores.append(frame_sharpness(frame))
                bar.update(1)
    finally:
        capture.release()
    if len(scores) < 2:
        raise InputError(f"cannot read the video: {len(scores)} frames decoded, at least 2 needed", video)
    if not (math.isfinite(fps) and fps > 0):
        fps = FALLBACK_FPS
    return np.asarray(scores), fps, size[0], size[1]


def _write_frames(video: Path, positions: np.ndarray, images_dir: Path, n_decoded: int, progress: bool) -> list[str]:
    """Second pass: decode again and write the frames at ``positions`` (ascending) as JPEG."""
    wanted = set(int(p) for p in positions)
    names = []
    capture = _open(video)
    try:
        with _bar(len(wanted), "video: writing frames", progress) as bar:
            index = 0
            while len(names) < len(wanted):
                if index in wanted:
                    ok, frame = capture.read()
                    if not ok or frame is None:
                        break
                    name = frame_name(index)
                    if not cv2.imwrite(str(images_dir / name), frame, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]):
                        raise InputError(f"cannot write the frame {name}", images_dir)
                    names.append(name)
                    bar.update(1)
                elif not capture.grab():
                    break
                index += 1
    finally:
        capture.release()
    if len(names) != len(wanted):
        raise InputError(
            f"the video decoded differently the second time ({n_decoded} frames first, stopped at {index}); "
            "re-encode it (e.g. ffmpeg -i IN -c:v libx264 OUT.mp4)",
            video,
        )
    return names


# --------------------------------------------------------------------------------------------
# the cache (video.json)


def _source_facts(video: Path, scene_dir: Path) -> dict:
    stat = video.stat()
    source = os.path.relpath(video.resolve(), scene_dir.resolve())
    return {"source": source, "size": stat.st_size, "mtime_ns": stat.st_mtime_ns}


def read_video_record(scene_dir: str | Path) -> dict | None:
    """The ``video.json`` of a scene folder as a dict, or None when there is none (or it is unreadable)."""
    path = Path(scene_dir) / VIDEO_FILE
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def _frames_from_record(record: dict, video: Path, scene_dir: Path) -> VideoFrames:
    return VideoFrames(
        video=video,
        scene_dir=scene_dir,
        indices=tuple(int(i) for i in record["indices"]),
        names=tuple(record["names"]),
        sharpness=tuple(float(s) for s in record["sharpness"]),
        blurred=tuple(int(i) for i in record["blurred"]),
        n_decoded=int(record["n_decoded"]),
        n_windows=int(record["n_windows"]),
        fps=float(record["fps"]),
        width=int(record["width"]),
        height=int(record["height"]),
        frames_per_second=float(record["frames_per_second"]),
        max_frames=int(record["max_frames"]),
        blur_ratio=float(record["blur_ratio"]),
        seconds=float(record["seconds"]),
        cached=True,
    )


def _reusable(record: dict | None, facts: dict, asked: dict, scene_dir: Path) -> VideoFrames | None:
    """The cached extraction when it is complete, of this very video, with the parameters asked
    (None in ``asked``: any), and its frames are all there; else None."""
    if not record or record.get("version") != _RECORD_VERSION or not record.get("complete"):
        return None
    if any(record.get(key) != value for key, value in facts.items()):
        return None
    if any(value is not None and record.get(key) != value for key, value in asked.items()):
        return None
    try:
        frames = _frames_from_record(record, scene_dir / facts["source"], scene_dir)
    except (KeyError, TypeError, ValueError):
        return None
    if not all((scene_dir / IMAGES_FOLDER / name).is_file() for name in frames.names):
        return None
    return frames


def _clear_previous(scene_dir: Path, record: dict | None) -> None:
    """Before extracting: delete what an earlier extraction wrote (its frames, the SfM cache), or
    refuse a folder whose images/ or sparse/ are not ours."""
    from scenelabel.data.io.common import list_images  # data.io imports this module
    from scenelabel.data.sfm import SFM_FOLDER, SPARSE_MODEL

    images_dir = scene_dir / IMAGES_FOLDER
    if record is None:
        if images_dir.is_dir() and list_images(images_dir):
            raise InputError(
                f"{IMAGES_FOLDER}/ already holds images not extracted from a video (no {VIDEO_FILE}): "
                "move them away, or load the folder itself to use them",
                scene_dir,
            )
        if (scene_dir / "sparse").exists():
            raise InputError(f"already holds a COLMAP model (sparse/) not made from a video (no {VIDEO_FILE})",
                             scene_dir)
        return
    for name in record.get("names", []) if isinstance(record.get("names"), list) else []:
        if isinstance(name, str) and Path(name).name == name:
            (images_dir / name).unlink(missing_ok=True)
    for path in images_dir.glob("frame_*.jpg") if images_dir.is_dir() else []:  # an interrupted extraction's
        path.unlink()
    shutil.rmtree(scene_dir / SPARSE_MODEL, ignore_errors=True)
    shutil.rmtree(scene_dir / SFM_FOLDER, ignore_errors=True)
    sparse = (scene_dir / SPARSE_MODEL).parent
    if sparse.is_dir() and not any(sparse.iterdir()):
        sparse.rmdir()


def _check_parameters(frames_per_second, max_frames, blur_ratio) -> None:
    """InputError naming the first parameter of :func:`frames_from_video` out of range."""
    if frames_per_second is not None and not (
        isinstance(frames_per_second, (int, float)) and not isinstance(frames_per_second, bool)
        and math.isfinite(frames_per_second) and frames_per_second > 0
    ):
        raise InputError(f"must be a positive number, got {frames_per_second!r}", field="frames_per_second")
    if max_frames is not None and (isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 2):
        raise InputError(f"must be an integer >= 2, got {max_frames!r}", field="max_frames")
    if not (isinstance(blur_ratio, (int, float)) and 0.0 <= blur_ratio < 1.0):
        raise InputError(f"must be in [0, 1), got {blur_ratio!r}", field="blur_ratio")


def _earlier_parameters(record: dict | None) -> dict:
    """The valid ``frames_per_second`` / ``max_frames`` of an earlier extraction's record (what None asks for)."""
    earlier, record = {}, record or {}
    fps, n = record.get("frames_per_second"), record.get("max_frames")
    if isinstance(fps, (int, float)) and not isinstance(fps, bool) and math.isfinite(fps) and fps > 0:
        earlier["frames_per_second"] = float(fps)
    if isinstance(n, int) and not isinstance(n, bool) and n >= 2:
        earlier["max_frames"] = n
    return earlier


def _write_record(path: Path, record: dict) -> None:
    atomic_write_bytes(path, (json.dumps(record, indent=2) + "\n").encode())


def frames_from_video(
    video_path: str | Path,
    out_dir: str | Path,
    frames_per_second: float | None = None,
    max_frames: int | None = None,
    blur_ratio: float = BLUR_RATIO,
    progress: bool = False,
) -> VideoFrames:
    """Choose sharp frames of a video and write them to ``out_dir/images/`` (cached).

    Args:
        video_path: the video (any container and codec OpenCV decodes).
        out_dir: the scene folder to write ``images/`` and ``video.json`` into (created).
        frames_per_second: target chosen frames per second of video; None: the earlier extraction's
            value when there is one (so a cached extraction is reused whatever its value), else
            :data:`FRAMES_PER_SECOND`.
        max_frames: at most this many frames; None: as ``frames_per_second`` (:data:`MAX_FRAMES`).
        blur_ratio: the blur test's ratio (:func:`blurred_frames`).
        progress: progress bars and a summary line on stderr.
    Returns:
        the :class:`VideoFrames` (``cached`` when an earlier extraction of the same video with the
        same parameters was reused without decoding).
    Raises:
        InputError: a missing or undecodable video, fewer than 2 frames, a bad parameter, or an
            ``images/`` (``sparse/``) in ``out_dir`` that no extraction wrote.
    """
    video, scene_dir = Path(video_path), Path(out_dir)
    if not video.is_file():
        raise InputError("video not found", video)
    _check_parameters(frames_per_second, max_frames, blur_ratio)
    scene_dir.mkdir(parents=True, exist_ok=True)
    facts = _source_facts(video, scene_dir)
    record = read_video_record(scene_dir)
    asked = {"frames_per_second": frames_per_second, "max_frames": max_frames, "blur_ratio": blur_ratio}
    cached = _reusable(record, facts, asked, scene_dir)
    if cached is not None:
        if progress:
            print(f"video: {cached.summary()}", file=sys.stderr, flush=True)
        return cached
    if record is None and (scene_dir / VIDEO_FILE).exists():
        record = {}  # an unreadable video.json of ours: still ours
    _clear_previous(scene_dir, record)

    earlier = _earlier_parameters(record)
    if frames_per_second is None:
        frames_per_second = earlier.get("frames_per_second", FRAMES_PER_SECOND)
    if max_frames is None:
        max_frames = earlier.get("max_frames", MAX_FRAMES)
    frames_per_second, max_frames = float(frames_per_second), int(max_frames)
    start = time.perf_counter()
    params = {"frames_per_second": frames_per_second, "max_frames": max_frames, "blur_ratio": float(blur_ratio)}
    _write_record(scene_dir / VIDEO_FILE, {"version": _RECORD_VERSION, "complete": False, **facts, **params})
    if progress:
        print(f"video: decoding {video} to choose frames ({frames_per_second:g} per second, at most {max_frames})",
              file=sys.stderr, flush=True)
    sharpness, fps, width, height = _score_frames(video, progress)
    n_windows = target_frame_count(len(sharpness), fps, frames_per_second, max_frames)
    radius = max(1, round(NEIGHBOUR_SECONDS * fps))
    chosen, blurred = choose_frames(sharpness, n_windows, radius, blur_ratio)
    if len(chosen) < 2:
        raise InputError(f"only {len(chosen)} sharp frames found in {len(sharpness)}: the video is too blurred", video)
    images_dir = scene_dir / IMAGES_FOLDER
    images_dir.mkdir(exist_ok=True)
    names = _write_frames(video, chosen, images_dir, len(sharpness), progress)
    frames = VideoFrames(
        video=video,
        scene_dir=scene_dir,
        indices=tuple(int(i) for i in chosen),
        names=tuple(names),
        sharpness=tuple(float(sharpness[i]) for i in chosen),
        blurred=tuple(int(i) for i in np.flatnonzero(blurred)),
        n_decoded=len(sharpness),
        n_windows=n_windows,
        fps=fps,
        width=width,
        height=height,
        seconds=time.perf_counter() - start,
        **params,
    )
    fields = {k: list(v) if isinstance(v, tuple) else v for k, v in vars(frames).items()}
    for key in ("video", "scene_dir", "cached"):
        del fields[key]
    _write_record(scene_dir / VIDEO_FILE, {"version": _RECORD_VERSION, "complete": True, **facts, **fields})
    if progress:
        print(f"video: {frames.summary()}", file=sys.stderr, flush=True)
    return frames


def prepare_video_scene(
    path: str | Path, frames_per_second: float | None = None, max_frames: int | None = None, progress: bool = False
) -> VideoFrames:
    """The frames of the video a scene path stands for, extracted (or reused) in its scene folder.

    Args:
        path: a video file (scene folder ``clip/`` beside ``clip.mp4``), or a folder holding
            ``video.json`` (the video it records) or exactly one video (the folder is the scene).
        frames_per_second, max_frames, progress: as :func:`frames_from_video`.
    Returns:
        the :class:`VideoFrames`; when a folder's recorded video is gone, its earlier frames
        (with a warning).
    Raises:
        InputError: no video there, several videos, or any :func:`frames_from_video` error.
    """
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() not in VIDEO_SUFFIXES:
            raise InputError(f"not a video: expected one of {', '.join(VIDEO_SUFFIXES)}", path)
        return frames_from_video(path, video_scene_dir(path), frames_per_second, max_frames, progress=progress)
    if not path.is_dir():
        raise InputError("video or scene folder not found", path)
    record = read_video_record(path)
    if record and isinstance(record.get("source"), str):
        video = path / record["source"]
        if not video.is_file():
            try:
                frames = _frames_from_record(record, video, path)
            except (KeyError, TypeError, ValueError):
                frames = None
            complete = frames is not None and record.get("complete")
            if not complete or not all((path / IMAGES_FOLDER / n).is_file() for n in frames.names):
                raise InputError(f"the video this folder's {VIDEO_FILE} records is gone, and its frames are incomplete",
                                 video)
            warnings.warn(f"{video} is gone: using the {len(frames.names)} frames extracted from it", stacklevel=3)
            return frames
        return frames_from_video(video, path, frames_per_second, max_frames, progress=progress)
    video = find_video(path)
    if video is None:
        raise InputError(f"no video ({', '.join(VIDEO_SUFFIXES)}) in the folder", path)
    return frames_from_video(video, path, frames_per_second, max_frames, progress=progress)
