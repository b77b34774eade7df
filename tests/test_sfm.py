"""Structure from motion (scene/sfm.py, `dc4gs-cl sfm`, `train --scene PHOTOS`): on the shared scenes' photos,
downsized and copied without their models, every photo registers and the cameras land where the shipped model has
them; a stopped run goes on from its database to the scene an uninterrupted one makes; bad input is one line,
exit 2, and nothing of a scene written."""
from __future__ import annotations

import argparse
import dataclasses
import io
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pycolmap
import pytest

from dc4gs_cl.apps.sfm import scene_for_training
from dc4gs_cl.cli import main
from dc4gs_cl.errors import InputError
from dc4gs_cl.files import exclusive_lock
from dc4gs_cl.geometry import similarity_alignment
from dc4gs_cl.scene import sfm
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.scene.sfm import DATABASE, SETTINGS_FILE, camera_centres, make_scene

from conftest import scene_path

# photos scaled to this width and SIFT's features kept few: seconds a scene on 2 cores
SIZES = {"fountain_p11": 320, "sceaux_castle": 480}
FAST = {"max_features": 1024}
ALIGNED = 0.01     # camera centres within this share of the scene's extent of the shipped model's
RESUMED_POINTS, RESUMED_CENTRES = 0.03, 0.002   # a resumed run's scene against an uninterrupted one's


def _downsized(source: Path, out: Path, width: int, names: list[str] | None = None) -> Path:
    out.mkdir(parents=True)
    for p in sorted(source.iterdir()):
        if names is None or p.name in names:
            buf = oiio.ImageBuf(str(p))
            height = round(buf.spec().height * width / buf.spec().width)
            assert oiio.ImageBufAlgo.resize(buf, roi=oiio.ROI(0, width, 0, height, 0, 1, 0, 3)).write(str(out / p.name))
    return out


@pytest.fixture(scope="module")
def photo_cache(tmp_path_factory):
    """Each shared scene's photos at its test size, made once per module."""
    made = {}

    def photos(name: str) -> Path:
        if name not in made:
            made[name] = _downsized(scene_path(name) / "images", tmp_path_factory.mktemp(name) / "images",
                                    SIZES[name])
        return made[name]
    return photos


def _copy(photos: Path, folder: Path) -> Path:
    shutil.copytree(photos, folder)
    return folder


def _error(centres: dict, reference: dict) -> float:
    """The largest distance of a camera centre from the reference's after the best similarity, over the
    reference's extent (1.1 x its largest distance from the centres' mean: scene.camera.scene_extent's rule)."""
    names = sorted(reference)
    X, Y = np.array([centres[n] for n in names]), np.array([reference[n] for n in names])
    s, R, t = similarity_alignment(X, Y)
    extent = 1.1 * np.linalg.norm(Y - Y.mean(axis=0), axis=1).max()
    return float(np.linalg.norm(s * X @ R.T + t - Y, axis=1).max() / extent)


def test_similarity_alignment_recovers_a_similarity(rng):
    X = rng.normal(size=(12, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    R = q * np.sign(np.linalg.det(q))
    s, t = rng.uniform(0.1, 10), rng.normal(size=3)
    s2, R2, t2 = similarity_alignment(X, s * X @ R.T + t)
    assert np.isclose(s2, s, rtol=1e-10) and np.allclose(R2, R, atol=1e-10) and np.allclose(t2, t, atol=1e-9)
    # a mirror image is no rotation: the best rotation leaves an error
    mirrored = X * np.array([1, 1, -1])
    _, Rm, _ = similarity_alignment(X, mirrored)
    assert np.isclose(np.linalg.det(Rm), 1.0)


@pytest.mark.parametrize("name, mapper", [(name, "incremental") for name in SIZES] + [("fountain_p11", "global")])
def test_every_photo_registers_where_the_shipped_model_has_it(name, mapper, photo_cache, tmp_path):
    """fountain_p11's shipped poses are ground truth, sceaux_castle's COLMAP's at 3x our size."""
    folder = _copy(photo_cache(name), tmp_path / name / "images").parent
    result = make_scene(folder, None, {**FAST, "mapper": mapper})
    assert result.scene == folder and result.left_out == [] and result.models[0] == result.photos
    reference = camera_centres(scene_path(name) / "sparse" / "0")
    centres = camera_centres(folder / "sparse" / "0")
    assert sorted(centres) == sorted(reference)
    assert _error(centres, reference) < ALIGNED
    record = json.loads((folder / SETTINGS_FILE).read_text())   # what rebuilds it
    assert record["pycolmap"] == pycolmap.__version__ and record["models"] == result.models
    assert record["settings"] == {**dataclasses.asdict(sfm.SfMSettings()), **FAST, "mapper": mapper}
    assert record["photos"] == sorted(p.name for p in (folder / "images").iterdir())
    scene = load_scene(folder)   # the loader reads it, undistorting the OPENCV camera
    assert len(scene.train) + len(scene.test) == result.photos and len(scene.points) > 100
    # train --scene of it again, with the same SfM flags: reused where it is
    args = argparse.Namespace(scene=str(folder), video_frames=None, no_progress=True, **FAST, mapper=mapper)
    scene_for_training(args, 1)
    assert args.scene == str(folder)


# temple_sparse_ring, 16 photos at 640x480 a ring of views some 22 degrees apart through a narrow lens, no EXIF: with
# the defaults OPENCV's fx, fy and distortion, fitted to the first two photos, go astray and 2 photos register
TEMPLE = {"camera_model": "SIMPLE_RADIAL", "affine_shape": True, "max_features": 2048}


def test_one_focal_length_and_affine_features_register_the_temple_ring(tmp_path):
    """One focal length (SIMPLE_RADIAL) keeps the mapper going; affine-shaped SIFT links the 3 photos that plain
    SIFT leaves in a model of their own (a 43-degree gap on one side, one photo on the other)."""
    shipped = scene_path("temple_sparse_ring") / "sparse" / "0"
    folder = _copy(scene_path("temple_sparse_ring") / "images", tmp_path / "temple" / "images").parent
    result = make_scene(folder, None, TEMPLE)
    assert result.left_out == [] and result.models[0] == result.photos
    centres = camera_centres(folder / "sparse" / "0")
    assert _error(centres, camera_centres(shipped)) < ALIGNED
    focal = next(iter(pycolmap.Reconstruction(str(folder / "sparse" / "0")).cameras.values())).focal_length
    assert abs(focal / next(iter(pycolmap.Reconstruction(str(shipped)).cameras.values())).focal_length_x - 1) < 0.1


def test_sequential_matching_registers_a_sequence(photo_cache, tmp_path):
    folder = _copy(photo_cache("fountain_p11"), tmp_path / "photos")   # the photos in the folder itself
    shown = io.StringIO()
    result = make_scene(folder, None, {**FAST, "exhaustive_up_to": 4, "overlap": 3}, sfm.Progress("bar", shown))
    for stage in ("features: 11 photos in", "matching: 27 pairs in", "mapping: 11 photos in"):   # bar, then line
        assert f"\rsfm: {stage.split(':')[0]}:   0%" in shown.getvalue() and f"\rsfm: {stage}" in shown.getvalue()
    assert result.scene == folder / sfm.SCENE_DIR and result.left_out == []
    assert len(sfm.image_pairs(11, sfm.SfMSettings(exhaustive_up_to=4, overlap=3))) == 3 * 11 - 6
    assert _error(camera_centres(result.scene / "sparse" / "0"),
                  camera_centres(scene_path("fountain_p11") / "sparse" / "0")) < ALIGNED
    assert (result.scene / "images" / "0000.jpg").samefile(folder / "0000.jpg")   # linked, not copied


def test_a_camera_per_folder_or_per_photo(photo_cache, tmp_path):
    """Per folder, each folder's photos share a camera (here of another size than the other folder's); per photo,
    each has its own."""
    photos = photo_cache("fountain_p11")
    names = sorted(p.name for p in photos.iterdir())
    folder = tmp_path / "two"
    _downsized(photos, folder / "images" / "a", 320, names[:6])
    _downsized(photos, folder / "images" / "b", 288, names[6:])
    result = make_scene(folder, None, {**FAST, "camera": "per-folder"})
    rec = pycolmap.Reconstruction(str(folder / "sparse" / "0"))
    assert result.left_out == [] and sorted((c.width, c.height) for c in rec.cameras.values()) == [(288, 192),
                                                                                                   (320, 213)]
    assert sorted(camera_centres(folder / "sparse" / "0")) == [f"a/{n}" for n in names[:6]] + [
        f"b/{n}" for n in names[6:]]
    result = make_scene(_copy(photos, tmp_path / "each" / "images").parent, None, {**FAST, "camera": "per-photo"})
    assert result.left_out == [] and pycolmap.Reconstruction(str(result.scene / "sparse" / "0")).num_cameras() == 11


def test_several_models_the_largest_kept_and_each_counted(photo_cache, tmp_path):
    """Two scenes' photos in one folder (a camera per folder): two models; the photos of the other are listed."""
    folder = tmp_path / "two_scenes"
    shutil.copytree(photo_cache("fountain_p11"), folder / "images" / "fountain")
    _downsized(photo_cache("sceaux_castle"), folder / "images" / "sceaux", 320,
               sorted(p.name for p in photo_cache("sceaux_castle").iterdir())[:10])
    result = make_scene(folder, None, {**FAST, "camera": "per-folder"})
    assert result.models == [11, 10] and result.left_out == [f"sceaux/{n}" for n in sorted(
        p.name for p in (folder / "images" / "sceaux").iterdir())]
    assert result.notes()[0] == "sfm: 2 models of 11, 10 photos: the largest is trained"
    assert result.notes()[1].startswith("sfm: 10 photos not registered, trained without: sceaux/") and \
        result.notes()[1].endswith(", ...")
    assert sorted(camera_centres(folder / "sparse" / "0")) == [f"fountain/{p.name}" for p in sorted(
        photo_cache("fountain_p11").iterdir())]


def test_a_stopped_run_goes_on_to_the_scene_an_uninterrupted_one_makes(photo_cache, tmp_path, monkeypatch):
    """Features and matches already in the database are not computed again, and the scene comes out the same:
    the photos are renumbered in name order after extraction, whichever thread wrote them first."""
    straight = make_scene(_copy(photo_cache("fountain_p11"), tmp_path / "straight" / "images").parent, None, FAST)
    folder = _copy(photo_cache("fountain_p11"), tmp_path / "stopped" / "images").parent
    names = sfm.find_photos(folder / "images")
    settings = sfm.SfMSettings(**FAST)
    asked = {"photos": [], "pairs": []}
    extract, match = pycolmap.extract_features, pycolmap.match_image_pairs

    def extract_features(database, root, image_names, **kw):
        asked["photos"] += image_names
        return extract(database, root, image_names=image_names, **kw)

    def match_image_pairs(database, pairing_options, **kw):
        asked["pairs"] += Path(pairing_options.match_list_path).read_text().splitlines()
        return match(database, pairing_options=pairing_options, **kw)
    monkeypatch.setattr(pycolmap, "extract_features", extract_features)
    monkeypatch.setattr(pycolmap, "match_image_pairs", match_image_pairs)
    # the first run stopped after 5 photos' features; the second after all the features and 7 pairs' matches
    first_pairs = [(0, j) for j in range(1, 5)] + [(1, 2), (1, 3), (2, 4)]
    with sfm._colmap_quiet():
        sfm._extract(folder / DATABASE, folder / "images", names[:5], None, settings, sfm.Progress("none"), -1)
        sfm._extract(folder / DATABASE, folder / "images", names, None, settings, sfm.Progress("none"), -1)
        with monkeypatch.context() as m:
            m.setattr(sfm, "image_pairs", lambda n, s: first_pairs)
            sfm._match(folder / DATABASE, names, settings, sfm.Progress("none"), -1)
    resumed = make_scene(folder, None, FAST)
    assert asked["photos"] == names   # each photo's features computed once
    assert len(asked["pairs"]) == len(set(asked["pairs"])) == 55 and asked["pairs"][:7] == [
        f"{names[a]} {names[b]}" for a, b in first_pairs]
    assert resumed.models == straight.models
    # the same scene up to pycolmap's approximate matcher: its per-photo FAISS index now and then comes out otherwise
    # under contending threads (2 of 511 resumed runs here, the pairs of one or two photos; once in CI, 740 points
    # against 747); features and verification (seeded per pair) were the same in every run, as was mapping given one
    # database (one thread, seeded)
    a, b = (pycolmap.Reconstruction(str(r.scene / "sparse" / "0")) for r in (straight, resumed))
    assert abs(a.num_points3D() - b.num_points3D()) <= RESUMED_POINTS * a.num_points3D()
    centres = camera_centres(resumed.scene / "sparse" / "0")
    assert _error(centres, camera_centres(straight.scene / "sparse" / "0")) < RESUMED_CENTRES
    np.testing.assert_allclose(a.cameras[1].params, b.cameras[1].params, rtol=1e-2, atol=1e-3)


def test_a_run_stopped_while_writing_leaves_no_scene_and_goes_on(photo_cache, tmp_path, monkeypatch):
    folder = _copy(photo_cache("fountain_p11"), tmp_path / "photos")

    def stopped(self, path):
        raise KeyboardInterrupt
    monkeypatch.setattr(pycolmap.Reconstruction, "write", stopped)
    with pytest.raises(KeyboardInterrupt):
        make_scene(folder, None, FAST)
    monkeypatch.undo()
    scene = folder / sfm.SCENE_DIR
    left = [p.name for p in scene.iterdir() if p.name.startswith(".") and p.name != sfm.LOCK]
    assert not (scene / "sparse").exists() and left == []
    with pytest.raises(InputError, match="not a COLMAP or NeRF scene"):
        load_scene(scene)
    (scene / ".mapping.killed").mkdir()   # what a run killed outright leaves
    assert make_scene(folder, None, FAST).left_out == [] and (scene / "sparse" / "0" / "images.bin").is_file()
    assert not (scene / ".mapping.killed").exists()


def test_unregistered_photos_are_listed_and_masks_keep_features_off(photo_cache, tmp_path, rng):
    folder = _copy(photo_cache("fountain_p11"), tmp_path / "scene" / "images").parent
    noise = (rng.uniform(size=(213, 320, 3)) * 255).astype(np.uint8)
    assert oiio.ImageBuf(noise).write(str(folder / "images" / "noise.jpg"))
    (folder / "masks").mkdir()
    for p in (folder / "images").iterdir():   # the right third of every photo masked out
        mask = np.full((213, 320, 1), 255, np.uint8)
        mask[:, 213:] = 0
        assert oiio.ImageBuf(mask).write(str(folder / "masks" / f"{p.name}.png"))
    result = make_scene(folder, None, FAST)
    assert result.left_out == ["noise.jpg"] and result.photos == 12
    assert any("1 photo not registered, trained without: noise.jpg" in line for line in result.notes())
    with pycolmap.Database.open(str(folder / DATABASE)) as db:
        xs = np.concatenate([db.read_keypoints(img.image_id)[:, 0] for img in db.read_all_images()])
    assert len(xs) > 1000 and xs.max() < 213
    scene = load_scene(folder)
    assert len(scene.train) + len(scene.test) == 11 and scene.mask(scene.train[0]) is not None


def test_train_makes_the_scene_then_reuses_it(photo_cache, tmp_path, capsys):
    folder = _copy(photo_cache("fountain_p11"), tmp_path / "photos")
    for k, run in enumerate(("first", "second")):
        assert main(["train", "--scene", str(folder), "--out", str(tmp_path / run), "--iterations", "10",
                     "--no-progress", "--lpips", "none", "--max-features", "1024"]) == 0
        err = capsys.readouterr().err
        said = [line for line in err.splitlines() if line.startswith("sfm: scene written") or "reusing" in line]
        assert len(said) == 1 and ("reusing" in said[0]) == (k == 1) and str(folder / sfm.SCENE_DIR) in said[0]
    assert main(["train", "--scene", str(folder), "--out", str(tmp_path / "third"), "--max-features", "512",
                 "--iterations", "10", "--no-progress"]) == 2
    assert "holds a scene made with other settings (max_features 1024 there, 512 now)" in capsys.readouterr().err


# a short training on each scene, the same settings and seed: 600 iterations at a quarter of fountain_p11's size
# (192x128), after SfM of its full-size photos with the default settings (at the photo cache's 320 px, SfM makes 747
# points, the shipped model has 4,778, and the 300-iteration runs differ by the start: 16.3 against 19.4 dB)
COMPARED = ["--iterations", "600", "-r", "4", "--seed", "0", "--lpips", "none", "--no-progress"]
# dB the recovered scene's test views may score below the shipped scene's: fountain_p11's 2 test views spread 2 dB
# over training seeds (README), and pycolmap's matcher makes the recovered scene differ now and then (README, SfM):
# one CI run scored 18.66 against 19.65 on Intel's runtime (0.5 dB was the bound until then)
PSNR_LOSS = 1.5


def _test_psnr(scene: Path, out: Path) -> float:
    assert main(["train", "--scene", str(scene), "--out", str(out), *COMPARED]) == 0
    return next(iter(json.loads((out / "results.json").read_text()).values()))["PSNR"]


def test_training_on_the_recovered_scene_scores_as_on_the_shipped_one(tmp_path):
    """fountain_p11's photos through SfM, then the same short training on the recovered scene and on the shipped
    one: their test views (the same photos) score within PSNR_LOSS (above passes: the shipped poses are another
    SfM's, no ground truth of the pixels). Measured: 19.61 dB on the recovered scene, 19.44 on the shipped one;
    once 18.66 against 19.65."""
    shipped = scene_path("fountain_p11")
    recovered = make_scene(_copy(shipped / "images", tmp_path / "recovered" / "images").parent)
    assert recovered.models[0] == 11
    ours, theirs = _test_psnr(recovered.scene, tmp_path / "on recovered"), _test_psnr(shipped, tmp_path / "on shipped")
    print(f"test PSNR: {ours:.2f} dB on the recovered scene, {theirs:.2f} on the shipped one")
    assert ours > theirs - PSNR_LOSS


def _refused(capsys, *args) -> str:
    assert main(["sfm", *map(str, args), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    return err


def test_bad_input_is_one_line_and_writes_no_scene(photo_cache, tmp_path, capsys):
    fountain = photo_cache("fountain_p11")
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no photos here")
    assert "no photos (.jpg" in _refused(capsys, empty)
    two = _downsized(fountain, tmp_path / "two", 64, ["0000.jpg", "0001.jpg"])
    assert "2 photos: SfM needs at least 3" in _refused(capsys, two)
    cut = _copy(fountain, tmp_path / "cut")
    data = (cut / "0004.jpg").read_bytes()
    (cut / "0004.jpg").write_bytes(data[:len(data) // 2])
    assert f"{cut / '0004.jpg'}: cannot decode image" in _refused(capsys, cut)
    mixed = _copy(fountain, tmp_path / "mixed")
    _downsized(fountain, tmp_path / "small", 160, ["0003.jpg"])
    shutil.copy(tmp_path / "small" / "0003.jpg", mixed / "0003.jpg")
    assert f"0003.jpg: is 160x106, {mixed / '0000.jpg'} 320x213: photos sharing a camera" in _refused(capsys, mixed)
    for folder in (empty, two, cut, mixed):
        assert not (folder / sfm.SCENE_DIR).exists()
    other = tmp_path / "other"
    shutil.copytree(scene_path("fountain_p11") / "sparse", other / "sparse")
    assert f"{other}: holds another scene" in _refused(capsys, fountain.parent, "--out", other)
    assert sorted(p.name for p in other.iterdir()) == ["sparse"]
    (tmp_path / "theirs" / "images").mkdir(parents=True)
    assert "holds images not made by dc4gs-cl sfm" in _refused(capsys, fountain.parent, "--out", tmp_path / "theirs")
    busy = _copy(fountain, tmp_path / "busy" / "images").parent
    with exclusive_lock(busy / sfm.LOCK, AssertionError):   # another run making the scene
        assert f"{busy}: is being made by another run (PID {os.getpid()})" in _refused(capsys, busy)
    assert not (busy / DATABASE).exists()


def test_photos_that_match_nothing_say_so(tmp_path, capsys, rng):
    folder = tmp_path / "noise"
    folder.mkdir()
    for k in range(3):
        assert oiio.ImageBuf((rng.uniform(size=(96, 128, 3)) * 255).astype(np.uint8)).write(str(folder / f"{k}.png"))
    assert "no two photos could be matched" in _refused(capsys, folder, "--max-features", "256")
    assert not (folder / sfm.SCENE_DIR / "sparse").exists()


def _blurred(pixels: np.ndarray, passes: int = 3, k: int = 5) -> np.ndarray:
    """A box blur of k x k, `passes` times (about a Gaussian's), edges clamped."""
    out = pixels.astype(np.float64)
    for _ in range(passes):
        for axis in (0, 1):
            pad = [(k // 2, k // 2) if a == axis else (0, 0) for a in range(3)]
            padded = np.pad(out, pad, mode="edge")
            out = sum(np.take(padded, range(i, i + out.shape[axis]), axis=axis) for i in range(k)) / k
    return out.round().astype(np.uint8)


def test_a_video_keeps_the_sharpest_frame_of_each_window_and_registers(photo_cache, tmp_path, capsys):
    """A clip of fountain_p11's photos, each three frames of which two are blurred (the sharp one first, second or
    third): the sharp frames are the ones kept, and SfM registers every one of them."""
    av = pytest.importorskip("av", reason="the video extra (PyAV) is not installed")
    photos = sorted(photo_cache("fountain_p11").iterdir())
    clip, sharp = tmp_path / "clip.mp4", []
    with av.open(str(clip), "w") as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = 320, 212, "yuv420p"
        stream.options = {"qscale": "2"}
        stream.codec_context.qmin = stream.codec_context.qmax = 2
        for k, p in enumerate(photos):
            pixels = np.asarray(oiio.ImageBuf(str(p)).get_pixels(oiio.UINT8))[:212]
            for position in range(3):
                if position == k % 3:
                    sharp.append(3 * k + position)
                frame = pixels if position == k % 3 else _blurred(pixels)
                container.mux(stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")))
        container.mux(stream.encode(None))
    assert main(["sfm", str(clip), "--video-frames", str(len(photos)), "--max-features", "1024", "--no-progress"]) == 0
    err = capsys.readouterr().err
    scene = tmp_path / "clip"
    kept = sorted(p.name for p in (scene / "images").iterdir())
    assert kept == [f"frame_{i:06d}.jpg" for i in sharp]
    assert "sfm: frames: 11 kept of clip.mp4" in err and "11 of 11 photos registered" in err
    assert json.loads((scene / SETTINGS_FILE).read_text())["settings"]["exhaustive_up_to"] == 0   # sequential
    # a second run reuses the frames and the scene; a video that does not decode is one line
    assert main(["sfm", str(clip), "--video-frames", "11", "--no-progress"]) == 0
    assert "reusing" in capsys.readouterr().err
    (tmp_path / "other" / "images").mkdir(parents=True)   # a folder's photos are never replaced by frames
    assert "holds images not made from a video" in _refused(capsys, clip, "--out", tmp_path / "other")
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(clip.read_bytes()[:200])
    assert "bad.mp4: cannot decode video" in _refused(capsys, bad)
    assert not (tmp_path / "bad").exists()


def test_a_video_without_pyav_says_how_to_get_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "av", None)
    clip = tmp_path / "clip.mp4"
    clip.write_bytes(b"\0" * 64)
    assert "pip install 'dc4gs-cl[video]'" in _refused(capsys, clip)


def test_sharpest_of_windows():
    from dc4gs_cl.scene.video_frames import sharpest_of_windows, sharpness
    assert sharpest_of_windows([1, 5, 2, 9, 0, 3, 3], 3) == [1, 3, 5]
    assert sharpest_of_windows([1, 2], 5) == [0, 1]
    rng = np.random.default_rng(0)
    image = rng.uniform(0, 255, (40, 50))
    assert sharpness(image) > 10 * sharpness(_blurred(image[..., None].astype(np.uint8))[..., 0])


def test_few_registered_photos_say_what_to_try():
    from dc4gs_cl.scene.sfm_settings import SfMSettings
    hint = "--camera-model SIMPLE_RADIAL --affine-shape"

    def notes(registered, **settings):
        return "\n".join(sfm.SfMResult(Path("s"), {}, [registered], 16, [], settings=SfMSettings(**settings)).notes())
    assert hint in notes(2) and hint in notes(7, camera_model="SIMPLE_RADIAL")
    assert hint not in notes(8) and hint not in notes(2, camera_model="SIMPLE_RADIAL", affine_shape=True)
