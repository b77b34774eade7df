"""`dc4gs-cl sfm PHOTOS [--out SCENE]`: a folder of photos or a video -> a COLMAP scene (scene/sfm.py; a video's
frames: scene/video_frames.py), and the same step inside `dc4gs-cl train --scene PHOTOS` (scene_for_training), with
the same flags."""
from __future__ import annotations

import argparse
import sys
from dataclasses import fields
from pathlib import Path

from ..errors import InputError
from ..scene.sfm_settings import CAMERA_MODELS, CAMERA_MODES, MAPPERS, SfMSettings
from ..scene.video_frames import DEFAULT_FRAMES, VIDEO_EXTENSIONS, is_video, video_scene

DEFAULTS = SfMSettings()
FLAG_HELP = {   # setting -> its flag's help; the flag is --<setting with dashes>
    "camera": f"one camera shared by every photo (convert.py's), one per folder of photos, or one per photo "
              f"(default {DEFAULTS.camera})",
    "camera_model": f"COLMAP camera model the photos are fitted with (default {DEFAULTS.camera_model}, as convert.py; "
                    "training renders it directly, or undistorted photos with train's --undistort)",
    "max_image_size": f"SIFT on photos scaled to at most this many pixels a side (default {DEFAULTS.max_image_size})",
    "max_features": f"SIFT features per photo at most (default {DEFAULTS.max_features})",
    "affine_shape": "SIFT features with affine shapes (COLMAP's estimate_affine_shape): photos taken further apart "
                    "match, features take longer (with --camera-model SIMPLE_RADIAL it registers every photo of "
                    "temple_sparse_ring, a ring of views 22 degrees apart)",
    "exhaustive_up_to": f"match every pair of photos up to this many photos, past it each photo with the next "
                        f"--overlap ones in name order (default {DEFAULTS.exhaustive_up_to})",
    "overlap": f"sequential matching: the photos each photo is matched with (default {DEFAULTS.overlap})",
    "mapper": f"incremental (COLMAP's mapper, convert.py's) or global (GLOMAP) (default {DEFAULTS.mapper})",
}
CHOICES = {"camera": CAMERA_MODES, "camera_model": CAMERA_MODELS, "mapper": MAPPERS}


def add_settings(p) -> None:
    """The SfM flags (for `sfm`, and for `train` in a group of their own); each defaults to None: not given."""
    for f in fields(SfMSettings):
        kind, flag = type(getattr(DEFAULTS, f.name)), "--" + f.name.replace("_", "-")
        if kind is bool:   # a switch: on when given, else None (not given) like the others
            p.add_argument(flag, action="store_true", default=None, help=FLAG_HELP[f.name])
            continue
        p.add_argument(flag, type=kind, choices=CHOICES.get(f.name), default=None,
                       metavar="N" if kind is int else None, help=FLAG_HELP[f.name])
    p.add_argument("--video-frames", type=int, default=None, metavar="N",
                   help=f"a video ({', '.join(VIDEO_EXTENSIONS)}): the frames kept, the sharpest of each of N windows "
                        f"of consecutive frames (default {DEFAULT_FRAMES}; matched sequentially unless "
                        "--exhaustive-up-to says otherwise; the video extra: pip install 'dc4gs-cl[video]')")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("photos", type=Path, help="folder of photos (the photos in it, or in its images/ subfolder; "
                                             "masks/NAME.png beside them keep features off masked-out pixels), or a "
                                             "video")
    p.add_argument("--out", type=Path, default=None,
                   help="scene folder (default: PHOTOS where the photos are in PHOTOS/images/, else PHOTOS/colmap; "
                        "a video's beside it, named as it less the extension); database.db there keeps the features "
                        "and matches, so a stopped run goes on from them")
    add_settings(p)
    p.add_argument("--no-progress", action="store_true", help="no progress display")


def given_settings(args) -> dict:
    """The SfM settings the command line gives (checked here, before anything is read)."""
    given = {f.name: v for f in fields(SfMSettings) if (v := getattr(args, f.name, None)) is not None}
    SfMSettings(**given)
    return given


def _progress(no_progress: bool):
    from ..scene.sfm import Progress
    from ..train.log import progress_mode
    return Progress(progress_mode(no_progress))


def _make(source: Path, out: Path | None, args):
    """The scene of a folder of photos or a video, said in a line per stage and one at the end."""
    from ..scene.sfm import make_scene
    given = given_settings(args)
    if args.video_frames is not None and not is_video(source):
        raise InputError(None, "--video-frames is for a video")
    if is_video(source):
        import time
        from ..scene.video_frames import frames_from_video
        out = out or video_scene(source)
        start = time.perf_counter()
        kept = frames_from_video(source, out, args.video_frames or DEFAULT_FRAMES)
        print(f"sfm: frames: {len(kept)} kept of {source.name} in {time.perf_counter() - start:.1f} s", file=sys.stderr)
        given.setdefault("exhaustive_up_to", 0)   # a video's frames: each matched with the next --overlap
        source = out
    result = make_scene(source, out, given, _progress(args.no_progress))
    for line in result.notes():
        print(line, file=sys.stderr)
    print(result.summary(), file=sys.stderr)
    return result


def cmd_sfm(args) -> int:
    given_settings(args)
    if not (args.photos.is_dir() or is_video(args.photos)):
        raise InputError(args.photos, "not a folder of photos nor a video (" + ", ".join(VIDEO_EXTENSIONS) + ")")
    print(f"scene: {_make(args.photos, args.out, args).scene}")
    return 0


def scene_for_training(args, processes: int) -> None:
    """train --scene PHOTOS (or a video): args.scene set to the scene SfM makes of them (or made before); SfM flags
    with any other scene are refused, as they would do nothing."""
    given = given_settings(args)
    scene = Path(args.scene) if args.scene else None
    from ..scene.builtin import BUILTIN_SCENE
    if scene is None or args.scene == BUILTIN_SCENE or not (is_video(scene) or _is_photo_folder(scene)):
        if given or args.video_frames is not None:
            flag = next(iter(given)).replace("_", "-") if given else "video-frames"
            raise InputError(None, f"--{flag} is for a --scene of photos or a video (SfM makes the scene); this "
                                   "scene has its own cameras")
        return
    if processes > 1:
        raise InputError(scene, "photos or a video: make the scene first, in one process (dc4gs-cl sfm "
                                f"{scene}), then train that scene")
    args.scene = str(_make(scene, None, args).scene)


def _is_photo_folder(path: Path) -> bool:
    """Photos with no scene yet, or a scene SfM made (it says whether the flags given agree with it)."""
    from ..scene.sfm import SETTINGS_FILE, is_photo_folder
    return is_photo_folder(path) or (path / SETTINGS_FILE).is_file()
