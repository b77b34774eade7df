"""A video as SfM's photos: the frames cut into `target` windows of consecutive frames, the sharpest frame of each
kept (the variance of its grey image's Laplacian: blur from motion or focus lowers it), written as JPEG files
named by their frame number (so their names sort in time order) into SCENE/images/, renamed into place whole.
SCENE/frames.json says which video and target they are of; a second run with the same reuses them.

Decoding through PyAV (the video extra: FFmpeg's libraries in its wheel), two passes over the video: the first
scores every frame, the second writes the chosen ones, so that no more than one frame is held at a time. The
module's own imports need neither PyAV nor OpenImageIO (the command line takes its names)."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..files import replace_folder, staging_folder, write_json

VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm")
DEFAULT_FRAMES = 100       # frames kept from a video (SfM's photos)
FRAMES_FILE = "frames.json"
VIDEO_HINT = "reading a video needs PyAV: pip install 'dc4gs-cl[video]'"


def is_video(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in VIDEO_EXTENSIONS


def video_scene(video: Path) -> Path:
    """Where a video's scene goes by default: beside it, named as it less its extension."""
    return video.with_suffix("")


def sharpness(grey: np.ndarray) -> float:
    """The variance of the 4-neighbour Laplacian of a (H, W) grey image (interior pixels)."""
    g = np.asarray(grey, np.float64)
    lap = 4 * g[1:-1, 1:-1] - g[:-2, 1:-1] - g[2:, 1:-1] - g[1:-1, :-2] - g[1:-1, 2:]
    return float(lap.var())


def sharpest_of_windows(scores: list[float], target: int) -> list[int]:
    """The index of the highest score in each of `target` windows of consecutive frames (all of them when there
    are no more than `target`); ties go to the earlier frame."""
    n = len(scores)
    if n <= target:
        return list(range(n))
    edges = np.linspace(0, n, target + 1).round().astype(int)
    return [int(a + np.argmax(scores[a:b])) for a, b in zip(edges[:-1], edges[1:])]


def _frames(video: Path):
    """(index, av.VideoFrame) of every frame of the video's first video stream; InputError where it cannot."""
    try:
        import av
    except ImportError:
        raise InputError(video, VIDEO_HINT) from None
    try:
        with av.open(str(video)) as container:
            if not container.streams.video:
                raise InputError(video, "holds no video stream")
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            yield from enumerate(container.decode(stream))
    except (av.FFmpegError, UnicodeDecodeError) as e:   # (PyAV decodes a stream's metadata as UTF-8)
        raise InputError(video, f"cannot decode video ({' '.join(str(e).split())})") from None


def frames_from_video(video: Path, scene: Path, target: int = DEFAULT_FRAMES) -> list[str]:
    """SCENE/images/ holding the sharpest frame of each of `target` windows of the video; the names written."""
    from .images import write_jpeg   # OpenImageIO: only here, the command line imports this module without it
    if target < 3:
        raise InputError(None, f"--video-frames {target} must be at least 3")
    record = {"video": video.name, "bytes": video.stat().st_size, "target": target}
    done = scene / FRAMES_FILE
    if done.is_file() and (scene / "images").is_dir():
        try:
            saved = json.loads(done.read_text())
        except (OSError, ValueError):
            saved = None
        if isinstance(saved, dict) and {k: saved.get(k) for k in record} == record:
            return saved["names"]
        raise InputError(scene, f"holds frames of another video or --video-frames ({done}): give another output "
                                "folder, or remove it")
    if (scene / "images").exists():   # never replaced: not made from a video here
        raise InputError(scene / "images", "holds images not made from a video by dc4gs-cl: give another output "
                                           "folder")
    scores = [sharpness(frame.to_ndarray(format="gray")) for _, frame in _frames(video)]
    if not scores:
        raise InputError(video, "holds no frames")
    keep = set(sharpest_of_windows(scores, target))
    staging = staging_folder(scene / "images")
    names = []
    try:
        for index, frame in _frames(video):
            if index in keep:
                names.append(f"frame_{index:06d}.jpg")
                write_jpeg(staging / names[-1], frame.to_ndarray(format="rgb24"))
        os.makedirs(scene, exist_ok=True)
        write_json(done, {**record, "frames": len(scores), "names": names})
        replace_folder(staging, scene / "images")
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return names
