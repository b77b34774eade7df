"""`dc4gs-cl sfm PHOTOS [--out SCENE]`: a folder of photos -> a COLMAP scene (scene/sfm.py), and the same step
inside `dc4gs-cl train --scene PHOTOS` (scene_for_training), with the same flags."""
from __future__ import annotations

import argparse
import sys
from dataclasses import fields
from pathlib import Path

from ..errors import InputError
from ..scene.sfm_settings import CAMERA_MODELS, CAMERA_MODES, MAPPERS, SfMSettings

DEFAULTS = SfMSettings()
FLAG_HELP = {   # setting -> its flag's help; the flag is --<setting with dashes>
    "camera": f"one camera shared by every photo (convert.py's), one per folder of photos, or one per photo "
              f"(default {DEFAULTS.camera})",
    "camera_model": f"COLMAP camera model the photos are fitted with (default {DEFAULTS.camera_model}, as convert.py; "
                    "training undistorts the photos)",
    "max_image_size": f"SIFT on photos scaled to at most this many pixels a side (default {DEFAULTS.max_image_size})",
    "max_features": f"SIFT features per photo at most (default {DEFAULTS.max_features})",
    "exhaustive_up_to": f"match every pair of photos up to this many photos, past it each photo with the next "
                        f"--overlap ones in name order (default {DEFAULTS.exhaustive_up_to})",
    "overlap": f"sequential matching: the photos each photo is matched with (default {DEFAULTS.overlap})",
    "mapper": f"incremental (COLMAP's mapper, convert.py's) or global (GLOMAP) (default {DEFAULTS.mapper})",
}
CHOICES = {"camera": CAMERA_MODES, "camera_model": CAMERA_MODELS, "mapper": MAPPERS}


def add_settings(p) -> None:
    """The SfM flags (for `sfm`, and for `train` in a group of their own); each defaults to None: not given."""
    for f in fields(SfMSettings):
        kind = type(getattr(DEFAULTS, f.name))
        p.add_argument("--" + f.name.replace("_", "-"), type=kind, choices=CHOICES.get(f.name), default=None,
                       metavar="N" if kind is int else None, help=FLAG_HELP[f.name])


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("photos", type=Path, help="folder of photos (the photos in it, or in its images/ subfolder); "
                                             "masks/NAME.png beside them keep features off masked-out pixels")
    p.add_argument("--out", type=Path, default=None,
                   help="scene folder (default: PHOTOS where the photos are in PHOTOS/images/, else PHOTOS/colmap); "
                        "database.db there keeps the features and matches, so a stopped run goes on from them")
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


def _report(result) -> None:
    for line in result.notes():
        print(line, file=sys.stderr)
    print(result.summary(), file=sys.stderr)


def cmd_sfm(args) -> int:
    from ..scene.sfm import make_scene
    given = given_settings(args)
    if not args.photos.is_dir():
        raise InputError(args.photos, "folder of photos not found")
    result = make_scene(args.photos, args.out, given, _progress(args.no_progress))
    _report(result)
    print(f"scene: {result.scene}")
    return 0


def scene_for_training(args, processes: int) -> None:
    """train --scene PHOTOS: args.scene set to the scene SfM makes of them (or made before); SfM flags with any
    other scene are refused, as they would do nothing."""
    given = given_settings(args)
    scene = Path(args.scene) if args.scene else None
    from ..scene.builtin import BUILTIN_SCENE
    if scene is None or args.scene == BUILTIN_SCENE or not _is_photo_folder(scene):
        if given:
            raise InputError(None, f"--{next(iter(given)).replace('_', '-')} is for a --scene of photos (SfM makes the "
                                   "scene); this scene has its own cameras")
        return
    if processes > 1:
        raise InputError(scene, "a folder of photos: make its scene first, in one process (dc4gs-cl sfm "
                                f"{scene}), then train that scene")
    from ..scene.sfm import make_scene
    result = make_scene(scene, None, given, _progress(args.no_progress))
    _report(result)
    args.scene = str(result.scene)


def _is_photo_folder(path: Path) -> bool:
    from ..scene.sfm import is_photo_folder
    return is_photo_folder(path)
