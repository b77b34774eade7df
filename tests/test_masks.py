"""Masks: a masks/ folder beside images/ (COLMAP's and nerfstudio's naming), nerfstudio's mask_path and
--alpha-mask are read and scaled with their images; masked pixels carry no loss and no densification
statistics, so what is painted under a mask is not learned; bad masks stop with one line naming the file."""
from dataclasses import replace

import numpy as np
import pytest

from dc4gs_cl.cli import main
from dc4gs_cl.config import TrainConfig
from dc4gs_cl.evaluation.metrics import psnr
from dc4gs_cl.scene.loader import load_scene
from dc4gs_cl.train import Trainer
from helpers import load_tool

fuzz_inputs = load_tool("fuzz_inputs")
W, H = fuzz_inputs.W, fuzz_inputs.H


def mask_pixels(rng) -> np.ndarray:
    keep = rng.uniform(size=(H, W)) > 0.3
    keep[2:9, 4:15] = False
    return keep


def write_mask(path, keep, channels=1):
    fuzz_inputs.write_image(path, np.repeat(keep[..., None].astype(np.float32), channels, axis=2), "uint8")


@pytest.mark.parametrize("naming", ["colmap", "same-name", "stem"])
def test_masks_folder_is_read_for_every_view(tmp_path, rng, naming):
    fuzz_inputs.nerf_scene(tmp_path, rng)
    scene = load_scene(tmp_path, test_every=0)
    keeps = {}
    for cam in scene.train:
        name = {"colmap": f"{cam.name}.png", "same-name": cam.name, "stem": cam.name.rsplit(".", 1)[0] + ".png"}[naming]
        keeps[cam.name] = mask_pixels(rng)
        write_mask(tmp_path / "masks" / name, keeps[cam.name], channels=3)
    scene = load_scene(tmp_path, test_every=0)
    for cam in scene.train:
        np.testing.assert_array_equal(scene.mask(cam), keeps[cam.name])
    half = load_scene(tmp_path, resolution=2, test_every=0)        # scaled with the image, thresholded again
    cam = half.train[0]
    assert half.mask(cam).shape == (cam.height, cam.width) and half.mask(cam).dtype == bool


def test_no_masks_means_every_pixel_counts(tmp_path, rng):
    fuzz_inputs.nerf_scene(tmp_path, rng)
    scene = load_scene(tmp_path, test_every=0)
    assert all(scene.mask(cam) is None for cam in scene.train)


def test_nerfstudio_mask_path_and_alpha_mask(tmp_path, rng):
    import json
    fuzz_inputs.nerf_scene(tmp_path, rng, channels=4)
    meta = json.loads((tmp_path / "transforms.json").read_text())
    keep = mask_pixels(rng)
    write_mask(tmp_path / "elsewhere" / "m0.png", keep)
    meta["frames"][0]["mask_path"] = "elsewhere/m0.png"
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    scene = load_scene(tmp_path, test_every=0)
    by_name = {c.name: c for c in scene.train}
    np.testing.assert_array_equal(scene.mask(by_name[meta["frames"][0]["file_path"]]), keep)
    assert scene.mask(by_name[meta["frames"][1]["file_path"]]) is None
    # --alpha-mask: the image's alpha (0.3 + 0.7 x, written by nerf_scene) is the mask, ANDed with mask_path's
    scene = load_scene(tmp_path, test_every=0, alpha_mask=True)
    by_name = {c.name: c for c in scene.train}
    alpha = scene.mask(by_name[meta["frames"][1]["file_path"]])
    x = (np.arange(W) / W)[None].repeat(H, 0)
    assert alpha[:, x[0] > 0.45].all() and not alpha[:, x[0] < 0.12].any()   # 0.5 at x = 0.29; noise 0.02
    first = scene.mask(by_name[meta["frames"][0]["file_path"]])
    assert not (first & ~keep).any() and (first != keep).any()


@pytest.mark.parametrize("problem", ["missing", "wrong-size", "mask_path-missing"])
def test_bad_masks_stop_naming_the_file(tmp_path, rng, capsys, problem):
    import json
    fuzz_inputs.nerf_scene(tmp_path, rng)
    names = [c.name for c in load_scene(tmp_path, test_every=0).train]
    if problem == "mask_path-missing":
        meta = json.loads((tmp_path / "transforms.json").read_text())
        meta["frames"][0]["mask_path"] = "nowhere.png"
        (tmp_path / "transforms.json").write_text(json.dumps(meta))
        named = "transforms.json"
    else:
        for name in names[1:]:
            write_mask(tmp_path / "masks" / f"{name}.png", mask_pixels(rng))
        if problem == "wrong-size":
            fuzz_inputs.write_image(tmp_path / "masks" / f"{names[0]}.png", np.ones((H + 2, W, 1), np.float32), "uint8")
        named = f"{names[0]}.png"
    out = tmp_path / "run"
    assert main(["train", "--scene", str(tmp_path), "--out", str(out), "--iterations", "5", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and named in err[0], err
    assert not out.exists()


def painted(scene, rng):
    """The built-in scene with a red block painted into every training view, and masks over the block."""
    cams = scene.train
    h, w = cams[0].height, cams[0].width
    keep = np.ones((h, w), bool)
    keep[h // 4: h // 2, w // 3: 2 * w // 3] = False

    def read_image(cam):
        image = scene.image(cam)
        if cam in cams:
            image = image.copy()
            image[~keep] = (1.0, 0.0, 0.0)
        return image
    return replace(scene, read_image=read_image), keep


def test_what_a_mask_covers_is_not_learned(rt, rng, tmp_path):
    """Red painted into the same pixels of every training view is learned without its mask (red floaters in
    the test views) and not with it: there the test views stay as a clean run's."""
    clean = load_scene("builtin", resolution=4)
    dirty, keep = painted(clean, rng)
    masked = replace(dirty, read_mask=lambda cam: keep if cam in clean.train else None)
    cfg = TrainConfig(scene="builtin", resolution=4, iterations=300)
    redness = {}
    for name, scene in (("clean", clean), ("painted", dirty), ("masked", masked)):
        trainer = Trainer(cfg, scene, rt, tmp_path / name)
        trainer.run(progress="none")
        renders = [trainer.renderer.render(trainer.params, c, trainer.sh_degree, clean.background).image(rt)
                   for c in clean.test]
        redness[name] = np.mean([r[..., 0] - r[..., 1:].mean(-1) for r in renders])
        redness[name + " PSNR"] = np.mean([psnr(r, clean.image(c)) for r, c in zip(renders, clean.test)])
    assert redness["painted"] > redness["clean"] + 0.02, redness            # the paint is learned ...
    assert abs(redness["masked"] - redness["clean"]) < 0.3 * (redness["painted"] - redness["clean"]), redness
    assert redness["masked PSNR"] > redness["painted PSNR"] + 1.0, redness  # ... and not under the mask
