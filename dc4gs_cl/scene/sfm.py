"""Structure from motion through pycolmap: a folder of photos -> a COLMAP scene our loader reads.

    PHOTOS/images/*.jpg (or PHOTOS/*.jpg)   the photos (subfolders allowed: --camera per-folder); PHOTOS/masks/
                                            NAME.png, where present, keeps features off the masked-out pixels
    SCENE/database.db                       features and matches: a killed run goes on from it
    SCENE/sfm.json                          the settings, pycolmap's version, the models, the photos left out
    SCENE/images/, SCENE/masks/             the photos (hard links, else copies) where SCENE is not PHOTOS
    SCENE/sparse/0/                         the largest model, OPENCV camera(s), rendered through directly

SCENE is PHOTOS itself when the photos are in PHOTOS/images/, else PHOTOS/colmap/. sparse/ is renamed into
place last, so a folder holding it holds a whole scene. The steps are those of the Inria code's convert.py
(COLMAP's feature_extractor, exhaustive_matcher, mapper), with its defaults: one shared OPENCV camera, SIFT at
most 3200 px and 8192 features, exhaustive matching (sequential past EXHAUSTIVE_UP_TO photos), incremental
mapping; features and matches already in the database are not computed again.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pycolmap

from ..errors import InputError
from ..files import exclusive_lock, replace_folder, staging_folder, write_json
from .colmap import model_dir
from .images import image_size, read_image
from .masks import MASKS_DIR
from .nerf import transforms_files
from .sfm_settings import SfMSettings

PHOTO_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
SCENE_DIR = "colmap"          # the scene made from a folder that holds its photos itself
DATABASE = "database.db"
SETTINGS_FILE = "sfm.json"
LOCK = ".sfm.lock"            # held by the run making the scene, the holder's PID inside
MIN_PHOTOS = 3                # two photos make a model, but leave nothing to test it on
SEED = 0                      # RANSAC's and the mapper's (the matcher's FAISS index stays unseeded: README)
BA_TOLERANCE = 1e-6           # convert.py's --Mapper.ba_global_function_tolerance
EXTRACT_CHUNK = 8             # photos per pycolmap call: a progress step, and where an interrupt is seen
MATCH_CHUNK = 64              # pairs per pycolmap call
MAPPING_THREADS = 1           # with 2, one database gave other models run to run; with 1 as fast on 2 cores
NAMES_SHOWN = 5               # photos named where some are left out
FEW_REGISTERED = 0.5          # below this fraction of the photos registered, the notes say what to try


@dataclass
class SfMResult:
    scene: Path
    seconds: dict[str, float]          # per stage; {} when an earlier run's scene was reused
    models: list[int]                  # each model's photo count, largest first
    photos: int
    left_out: list[str]                # photos the trained model does not hold
    reused: bool = False
    settings: SfMSettings | None = None

    def summary(self) -> str:
        """The one line train and sfm print."""
        if self.reused:
            return f"sfm: reusing the scene in {self.scene} ({self.models[0]} of {self.photos} photos registered)"
        return (f"sfm: scene written to {self.scene} in {sum(self.seconds.values()):.1f} s ("
                + ", ".join(f"{k} {v:.1f} s" for k, v in self.seconds.items())
                + f"), {self.models[0]} of {self.photos} photos registered")

    def notes(self) -> list[str]:
        """What the user should know about the models and the photos left out (printed with the summary)."""
        lines = []
        if len(self.models) > 1:
            lines.append(f"sfm: {len(self.models)} models of {', '.join(map(str, self.models))} photos: "
                         "the largest is trained")
        if self.left_out:
            shown = ", ".join(self.left_out[:NAMES_SHOWN]) + (", ..." if len(self.left_out) > NAMES_SHOWN else "")
            lines.append(f"sfm: {len(self.left_out)} photo{'s' * (len(self.left_out) > 1)} not registered, "
                         f"trained without: {shown}")
        wider = self.settings is not None and (self.settings.camera_model != "SIMPLE_RADIAL"
                                               or not self.settings.affine_shape)
        if wider and self.models[0] < FEW_REGISTERED * self.photos:
            # photos with no EXIF focal length start from COLMAP's guess (1.2 x the larger side), which OPENCV's
            # four intrinsics can drift from; one focal length and affine SIFT took temple_sparse_ring 2 -> 16 of 16
            lines.append("sfm: fewer than half the photos registered: for photos far apart or with no EXIF focal "
                         "length try --camera-model SIMPLE_RADIAL --affine-shape (a new --out, or remove the scene)")
        return lines


def photo_root(folder: Path) -> Path:
    """Where a folder's photos are: its images/ subfolder where it has one, else the folder itself."""
    return folder / "images" if (folder / "images").is_dir() else folder


def default_scene(folder: Path) -> Path:
    return folder if photo_root(folder) != folder else folder / SCENE_DIR


def find_photos(root: Path, scene: Path | None = None) -> list[str]:
    """The photos under `root` (relative POSIX paths, sorted: the capture's order), leaving out hidden entries,
    the folders a scene made beside them holds (colmap/, masks/) and the scene folder, where it is inside."""
    names = []
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(".")
                             and not (here == root and d in (SCENE_DIR, MASKS_DIR))
                             and (scene is None or here / d != scene))
        names += [(here / f).relative_to(root).as_posix() for f in filenames
                  if not f.startswith(".") and f.lower().endswith(PHOTO_EXTENSIONS)]
    return sorted(names)


def is_photo_folder(path: Path) -> bool:
    """A folder that is no COLMAP or NeRF scene and holds photos (itself, or in images/)."""
    return (path.is_dir() and model_dir(path) is None and not transforms_files(path)
            and bool(find_photos(photo_root(path))))


class Progress:
    """A bar per stage (mode "bar"), a line per stage at its end ("bar" and "lines"), or nothing ("none")."""

    def __init__(self, mode: str = "lines", stream=None):
        self.mode, self.stream = mode, stream or sys.stderr

    @contextlib.contextmanager
    def stage(self, label: str, total: int, unit: str, done: int = 0):
        """Yields advance(n): n more of the stage's `total` done; `done` of them were by an earlier run."""
        bar = None
        if self.mode == "bar":
            from tqdm import tqdm
            bar = tqdm(total=total, initial=done, desc=f"sfm: {label}", unit=unit, leave=False, dynamic_ncols=True,
                       file=self.stream)
        start = time.perf_counter()
        yield (bar.update if bar is not None else lambda n=1: None)
        if bar is not None:
            bar.close()
        if self.mode != "none":
            earlier = f" ({done} by an earlier run)" if done else ""
            print(f"sfm: {label}: {total} {unit}{'s' * (total != 1)}{earlier} in {time.perf_counter() - start:.1f} s",
                  file=self.stream)


def make_scene(photos: Path, scene: Path | None = None, given: dict | None = None, progress: Progress | None = None,
               threads: int = -1) -> SfMResult:
    """The COLMAP scene of the photos in `photos` (itself or its images/), in `scene` (default: default_scene),
    made by SfM, or an earlier run's there made (or being made: it goes on) from the same photos. given: the
    settings (SfMSettings' fields) asked for; the others are the earlier run's, else the defaults. threads:
    extraction's and matching's (-1: every core)."""
    progress = progress or Progress("none")
    photos, scene = Path(photos), Path(scene) if scene is not None else default_scene(Path(photos))
    root = photo_root(photos)
    names = find_photos(root, scene)
    settings = SfMSettings(**{**_saved_settings(scene), **(given or {})})
    record = {"settings": dataclasses.asdict(settings), "photos": names}
    earlier = _earlier_run(scene, record)
    if earlier is not None:
        return earlier
    if root != scene / "images" and (scene / "images").exists() and not (scene / SETTINGS_FILE).is_file():
        raise InputError(scene / "images", "holds images not made by dc4gs-cl sfm (never replaced): give another "
                                           "output folder")
    masks = _masks(photos, names)
    start = time.perf_counter()   # the photos' check counts as the features' time: both read every photo
    check_photos(root, names, settings)
    scene.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(scene / LOCK, lambda holder: InputError(
            scene, f"is being made by another run (PID {holder}): wait for it to end, or give another --out")):
        earlier = _earlier_run(scene, record)   # (a run that ended between the check above and here made it)
        if earlier is not None:
            return earlier
        _remove_leftovers(scene)
        database = scene / DATABASE
        seconds = {}
        with _colmap_quiet():
            write_json(scene / SETTINGS_FILE, record)   # what database.db holds features of
            _extract(database, root, names, masks, settings, progress, threads)
            seconds["features"] = time.perf_counter() - start
            start = time.perf_counter()
            _match(database, names, settings, progress, threads)
            seconds["matching"] = time.perf_counter() - start
            start = time.perf_counter()
            models = _map(database, root, scene, names, settings, progress)
            seconds["mapping"] = time.perf_counter() - start
        if not models:
            raise InputError(root, "no two photos could be matched: SfM found no model (try photos that overlap more, "
                                   "with texture in view; more features, --max-features; for photos far apart "
                                   "--camera-model SIMPLE_RADIAL --affine-shape; or --camera per-photo for photos of "
                                   "several cameras)")
        largest = models[0]
        registered = {img.name for img in largest.images.values() if img.has_pose}
        result = SfMResult(scene, seconds, [m.num_reg_images() for m in models], len(names),
                           [n for n in names if n not in registered], settings=settings)
        _write_scene(largest, root, photos, scene, names, masks, {**record, **_result_record(result)})
        return result


LEFTOVERS = (".mapping.*", ".database.*.db", ".sparse.*.staging", ".images.*.staging", ".masks.*.staging")


def _remove_leftovers(scene: Path) -> None:
    """What a killed run left of its temporary folders and files (theirs are removed on any other exit)."""
    for pattern in LEFTOVERS:
        for p in scene.glob(pattern):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)


def _saved_settings(scene: Path) -> dict:
    """The settings an earlier run in `scene` recorded (those SfMSettings still has), {} where there is none."""
    try:
        saved = json.loads((scene / SETTINGS_FILE).read_text()).get("settings")
    except (OSError, ValueError, AttributeError):
        return {}   # none, or unreadable: _earlier_run says so
    names = {f.name for f in dataclasses.fields(SfMSettings)}
    return {k: v for k, v in saved.items() if k in names} if isinstance(saved, dict) else {}


def _earlier_run(scene: Path, record: dict) -> SfMResult | None:
    """An earlier run's whole scene in `scene` from these photos and settings (None: there is none yet); a scene
    made otherwise is refused (nothing is written over it), as is a database made for other settings."""
    saved_path = scene / SETTINGS_FILE
    saved = None
    if saved_path.is_file():
        try:
            saved = json.loads(saved_path.read_text())
        except (OSError, ValueError) as e:
            raise InputError(saved_path, f"cannot read ({e}): remove it to make the scene again") from None
    whole = model_dir(scene) is not None or bool(transforms_files(scene))
    if whole and (saved is None or "models" not in saved):
        raise InputError(scene, "holds another scene (not made from these photos by dc4gs-cl sfm): give another "
                                "output folder")
    if saved is not None and {k: saved.get(k) for k in record} != record:
        theirs = saved.get("settings") or {}
        differs = [f"{k} {theirs.get(k)!r} there, {v!r} now" for k, v in record["settings"].items()
                   if theirs.get(k) != v]
        made = "made" if whole else "being made"
        raise InputError(scene, f"holds a scene {made} " + (f"with other settings ({', '.join(differs)})" if differs
                                                             else "from other photos")
                         + f": give another output folder, or remove {scene} to make it again")
    if not whole:
        return None
    return SfMResult(scene, {}, saved["models"], len(saved["photos"]), saved["left_out"], reused=True,
                     settings=SfMSettings(**record["settings"]))


def _masks(photos: Path, names: list[str]) -> Path | None:
    """PHOTOS/masks/, where it exists, holding NAME.png for every photo (COLMAP's naming)."""
    masks = photos / MASKS_DIR
    if not masks.is_dir():
        return None
    for n in names:
        if not (masks / f"{n}.png").is_file():
            raise InputError(masks / f"{n}.png", f"no mask for photo {n!r} (with a {MASKS_DIR}/ folder, every "
                                                 "photo needs one, named as the photo plus .png)")
    return masks


def check_photos(root: Path, names: list[str], settings: SfMSettings) -> None:
    """Enough photos, each decoding whole, of one size wherever they share a camera; before anything is written."""
    if not names:
        raise InputError(root, f"no photos ({', '.join(PHOTO_EXTENSIONS)}) in this folder")
    if len(names) < MIN_PHOTOS:
        raise InputError(root, f"{len(names)} photo{'s' * (len(names) > 1)}: SfM needs at least {MIN_PHOTOS} "
                               "overlapping photos")
    first: dict[str, tuple[str, tuple[int, int]]] = {}
    for n in names:
        read_image(root / n)   # a truncated or unreadable photo is named here, not lost inside COLMAP
        size = image_size(root / n)
        other, other_size = first.setdefault(_camera_of(n, settings.camera), (n, size))
        if size != other_size:
            raise InputError(root / n, f"is {size[0]}x{size[1]}, {root / other} {other_size[0]}x{other_size[1]}: "
                                       f"photos sharing a camera (--camera {settings.camera}) must have one size; "
                                       "try --camera per-photo")


def _camera_of(name: str, mode: str) -> str:
    """Which camera a photo is taken with, as a key: its folder's, its own or the one every photo shares."""
    return {"shared": "", "per-folder": str(Path(name).parent), "per-photo": name}[mode]


def _camera_groups(names: list[str], mode: str) -> dict[str, list[str]]:
    groups: dict[str, list[str]] = {}
    for n in names:
        groups.setdefault(_camera_of(n, mode), []).append(n)
    return groups


@contextlib.contextmanager
def _colmap_quiet():
    """COLMAP's log (glog, on stderr) down to its errors while SfM runs: the stages say what happened."""
    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = pycolmap.logging.ERROR
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = level


@contextlib.contextmanager
def _database(path: Path):
    db = pycolmap.Database.open(str(path))
    try:
        yield db
    finally:
        db.close()


def _extracted(database: Path) -> dict[str, pycolmap.Image]:
    """The photos whose features the database holds, by name."""
    if not database.exists():
        return {}
    with _database(database) as db:
        return {img.name: img for img in db.read_all_images()
                if db.exists_keypoints(img.image_id) and db.exists_descriptors(img.image_id)}


def _extract(database: Path, root: Path, names: list[str], masks: Path | None, settings: SfMSettings,
             progress: Progress, threads: int) -> None:
    """SIFT features of the photos the database lacks, in chunks per camera (a chunk after a camera's first takes
    its camera: pycolmap would make one per call); then the photos renumbered in name order, so that the scene
    does not depend on which thread finished first."""
    done = _extracted(database)
    reader = pycolmap.ImageReaderOptions(camera_model=settings.camera_model)
    if masks is not None:
        reader.mask_path = str(masks)
    extraction = pycolmap.FeatureExtractionOptions(max_image_size=settings.max_image_size, num_threads=threads)
    extraction.sift.max_num_features = settings.max_features
    extraction.sift.estimate_affine_shape = settings.affine_shape
    # per camera, the photos of each call; a call after a camera's first takes that camera (a call makes its own)
    per_photo = settings.camera == "per-photo"
    groups = [names] if per_photo else _camera_groups(names, settings.camera).values()
    with progress.stage("features", len(names), "photo", len(done.keys() & set(names))) as advance:
        for group in groups:
            camera = -1 if per_photo else next((done[n].camera_id for n in group if n in done), -1)
            todo = [n for n in group if n not in done]
            for at in range(0, len(todo), EXTRACT_CHUNK):
                reader.existing_camera_id = camera
                chunk = todo[at:at + EXTRACT_CHUNK]
                pycolmap.extract_features(str(database), str(root), image_names=chunk,
                                          camera_mode=pycolmap.CameraMode.PER_IMAGE if per_photo
                                          else pycolmap.CameraMode.SINGLE,
                                          reader_options=reader, extraction_options=extraction)
                if not per_photo:
                    camera = _extracted(database)[chunk[0]].camera_id
                advance(len(chunk))
    missing = [n for n in names if n not in _extracted(database)]
    if missing:
        raise InputError(root / missing[0], "COLMAP could not read this photo")
    _renumber(database)


def _renumber(database: Path) -> None:
    """Image (and frame) ids in name order, written as a new database swapped in; only before any matching."""
    with _database(database) as db:
        images = sorted(db.read_all_images(), key=lambda i: i.image_id)
        ordered = sorted(images, key=lambda i: i.name)
        if [i.image_id for i in ordered] == list(range(1, len(images) + 1)) or db.num_matched_image_pairs():
            return
        fd, tmp = tempfile.mkstemp(prefix=".database.", suffix=".db", dir=database.parent)
        os.close(fd)
        os.unlink(tmp)
        try:
            with _database(Path(tmp)) as new:
                for cam in db.read_all_cameras():
                    new.write_camera(cam, use_camera_id=True)
                for rig in db.read_all_rigs():
                    new.write_rig(rig, use_rig_id=True)
                frames = {f.frame_id: f for f in db.read_all_frames()}
                for image_id, img in enumerate(ordered, 1):
                    frame = pycolmap.Frame()
                    frame.frame_id, frame.rig_id = image_id, frames[img.frame_id].rig_id
                    frame.add_data_id(pycolmap.data_t(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, img.camera_id),
                                                      image_id))
                    new.write_frame(frame, use_frame_id=True)
                    copy = pycolmap.Image(name=img.name, camera_id=img.camera_id, image_id=image_id)
                    copy.frame_id = image_id
                    new.write_image(copy, use_image_id=True)
                    new.write_keypoints(image_id, db.read_keypoints(img.image_id))
                    new.write_descriptors(image_id, db.read_descriptors(img.image_id))
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
    os.replace(tmp, database)


def image_pairs(count: int, settings: SfMSettings) -> list[tuple[int, int]]:
    """The pairs (i < j, indices in name order) to match: all of them, or each photo with the next `overlap`."""
    reach = settings.overlap if settings.sequential(count) else count
    return [(i, j) for i in range(count) for j in range(i + 1, min(i + reach + 1, count))]


def _match(database: Path, names: list[str], settings: SfMSettings, progress: Progress, threads: int) -> None:
    """Match and verify the pairs the database has no two-view geometry of, in chunks."""
    pairs = image_pairs(len(names), settings)
    with _database(database) as db:
        ids = {img.name: img.image_id for img in db.read_all_images()}
        todo = [(a, b) for a, b in pairs if not db.exists_two_view_geometry(ids[names[a]], ids[names[b]])]
    matching = pycolmap.FeatureMatchingOptions(num_threads=threads)
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = SEED
    with progress.stage("matching", len(pairs), "pair", len(pairs) - len(todo)) as advance, \
            tempfile.TemporaryDirectory(prefix="dc4gs-pairs-") as tmp:
        listing = Path(tmp) / "pairs.txt"
        for at in range(0, len(todo), MATCH_CHUNK):
            chunk = todo[at:at + MATCH_CHUNK]
            listing.write_text("".join(f"{names[a]} {names[b]}\n" for a, b in chunk))
            pycolmap.match_image_pairs(str(database), matching_options=matching,
                                       pairing_options=pycolmap.ImportedPairingOptions(match_list_path=str(listing)),
                                       verification_options=verification)
            advance(len(chunk))


def _map(database: Path, root: Path, scene: Path, names: list[str], settings: SfMSettings,
         progress: Progress) -> list[pycolmap.Reconstruction]:
    """The models SfM finds, largest first (written to a temporary folder that goes with the call); the bar counts
    the photos registered as the mapper registers them, and ends at the largest model's."""
    counted = [0]

    def registered(n: int) -> None:
        counted[0] += n
        advance(n)
    with tempfile.TemporaryDirectory(prefix=".mapping.", dir=scene) as out, \
            progress.stage("mapping", len(names), "photo") as advance:
        if settings.mapper == "global":
            options = pycolmap.GlobalPipelineOptions(num_threads=MAPPING_THREADS, random_seed=SEED)
            models = pycolmap.global_mapping(str(database), str(root), out, options)
        else:
            options = pycolmap.IncrementalPipelineOptions(num_threads=MAPPING_THREADS, random_seed=SEED,
                                                          ba_global_function_tolerance=BA_TOLERANCE)
            models = pycolmap.incremental_mapping(str(database), str(root), out, options,
                                                  initial_image_pair_callback=lambda: registered(2),
                                                  next_image_callback=lambda: registered(1))
        models = distinct(sorted(models.values(), key=lambda m: -m.num_reg_images()))
        advance((models[0].num_reg_images() if models else 0) - counted[0])
    return models


def distinct(models: list[pycolmap.Reconstruction]) -> list[pycolmap.Reconstruction]:
    """The models (largest first) less those whose photos a larger one holds all of: the mapper keeps its first
    attempt however small (often 2 photos it could not grow from), though a later one holds them too."""
    kept, held = [], []
    for m in models:
        names = {img.name for img in m.images.values() if img.has_pose}
        if not any(names <= h for h in held):
            kept.append(m)
            held.append(names)
    return kept


def _result_record(result: SfMResult) -> dict:
    return {"pycolmap": pycolmap.__version__, "models": result.models, "left_out": result.left_out,
            "seconds": {k: round(v, 3) for k, v in result.seconds.items()}}


def _write_scene(model: pycolmap.Reconstruction, root: Path, photos: Path, scene: Path, names: list[str],
                 masks: Path | None, record: dict) -> None:
    """images/ and masks/ (where the photos are elsewhere), sfm.json, then sparse/ renamed in: the scene is whole
    once sparse/ is there."""
    if root != scene / "images":
        _link_folder(root, scene / "images", names)
    if masks is not None and masks != scene / MASKS_DIR:
        _link_folder(masks, scene / MASKS_DIR, [f"{n}.png" for n in names])
    write_json(scene / SETTINGS_FILE, record)
    staging = _staging(scene / "sparse")
    try:
        (staging / "0").mkdir()
        model.write(str(staging / "0"))
        replace_folder(staging, scene / "sparse")
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _link_folder(source: Path, final: Path, names: list[str]) -> None:
    """`final` holding `names` from `source`: hard links where the file system allows, copies elsewhere."""
    staging = _staging(final)
    try:
        for n in names:
            (staging / n).parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(source / n, staging / n)
            except OSError:
                shutil.copy2(source / n, staging / n)
        replace_folder(staging, final)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _staging(final: Path) -> Path:
    """staging_folder's, with the permissions of a folder made here (mkdtemp makes it private)."""
    staging = staging_folder(final)
    umask = os.umask(0)
    os.umask(umask)
    staging.chmod(0o777 & ~umask)
    return staging


def camera_centres(model_folder: Path) -> dict[str, np.ndarray]:
    """Each registered photo's camera centre in a COLMAP model folder, by name (for comparing two scenes)."""
    rec = pycolmap.Reconstruction(str(model_folder))
    return {img.name: np.asarray(img.projection_center(), np.float64) for img in rec.images.values() if img.has_pose}
