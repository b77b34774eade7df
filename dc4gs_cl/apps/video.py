"""`render --path`: a camera path's frames (scene/paths.py) as numbered PNGs, and a video of them where ffmpeg is
on PATH (OpenImageIO writes image sequences, not videos; nothing else here encodes one)."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from ..errors import OutputError
from ..files import replace_folder, staging_folder, write_atomic
from ..scene.images import write_png

FRAME_PATTERN = "%05d.png"   # frame names: the path's camera names (scene/paths.py) plus .png


def render_path(rt, renderer, gaussians, cams, background, frames_dir: Path, video: Path, fps: int) -> None:
    """Render `cams` into frames_dir (replaced whole once every frame is written) and, with ffmpeg, encode them
    to `video` (H.264 where the ffmpeg build has it, yuv420p so that browsers and players take it)."""
    staging = staging_folder(frames_dir)
    try:
        for cam in cams:
            renderer.context.check.at = f"path frame {cam.name}"
            write_png(staging / f"{cam.name}.png", renderer.render(gaussians, cam, background=background).image(rt))
        replace_folder(staging, frames_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    print(f"wrote {len(cams)} frames to {frames_dir}", file=sys.stderr)
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        print(f"no ffmpeg on PATH, so no video; with it: ffmpeg -framerate {fps} -i {frames_dir / FRAME_PATTERN} "
              f"-pix_fmt yuv420p {video}", file=sys.stderr)
        return

    def encode(tmp: Path) -> None:
        done = subprocess.run([ffmpeg, "-nostdin", "-loglevel", "error", "-framerate", str(fps),
                               "-i", str(frames_dir / FRAME_PATTERN), "-pix_fmt", "yuv420p",
                               # yuv420p needs even sides
                               "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-f", "mp4", str(tmp)],
                              capture_output=True, text=True)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["no message"])[-1]
            raise OutputError(video, f"ffmpeg failed ({last}); the frames are in {frames_dir}")
    write_atomic(video, encode)
    print(f"wrote {video} ({len(cams)} frames at {fps} fps)", file=sys.stderr)
