"""Bad input, fuzzed: tools/fuzz_inputs.py mutates every file dc4gs-cl reads (truncation, byte flips, zero
length, NaN/Inf, huge counts, wrong JSON types, wrong image sizes; paths with spaces and non-ASCII letters)
and every case must read as before or stop with one line naming the file. CI runs a fixed budget from a fresh
seed (printed; DC4GS_TEST_SEED repeats it); `python tools/fuzz_inputs.py --cases 300` runs a larger one.
Also the faults the fuzzer found or the issue named, each as its own regression test."""
import struct
import zlib
from pathlib import Path

import pytest

from dc4gs_cl.cli import main
from dc4gs_cl.errors import InputError
from dc4gs_cl.scene.loader import load_scene
from helpers import load_tool

fuzz_inputs = load_tool("fuzz_inputs")

CASES_PER_FORMAT = 60   # CI budget: 24 formats x 60 = 1,440 cases (about 15 s on 2 cores)


@pytest.fixture
def seed(rng) -> int:
    return int(rng.integers(2**31))


@pytest.mark.parametrize("fmt", list(fuzz_inputs.FORMATS))
def test_every_mutated_input_reads_right_or_stops_with_one_line_naming_the_file(fmt, seed):
    results = fuzz_inputs.fuzz(CASES_PER_FORMAT, seed, [fmt], cli=True, log=lambda line: None)
    findings = [f"{c.mutation} (seed {c.seed}): {c.finding}: {c.message}" for c in results if c.finding]
    assert not findings, (f"repeat with: python tools/fuzz_inputs.py --format '{fmt}' --seed {seed} "
                          f"--cases {CASES_PER_FORMAT}\n" + "\n".join(findings))
    outcomes = {c.outcome for c in results}
    assert "error" in outcomes     # the mutations reach the reader's checks (not all absorbed)


def build(fmt: str, tmp_path, rng) -> Path:
    return fuzz_inputs.FORMATS[fmt].build(tmp_path / fuzz_inputs.FOLDER, rng)


def stops_naming(path: Path, call, *args) -> str:
    with pytest.raises(InputError) as e:
        call(*args)
    assert str(path) in str(e.value) and "\n" not in str(e.value)
    return str(e.value)


def test_a_truncated_jpeg_is_not_trained_on(tmp_path, rng, capsys):
    """The issue's case: OpenImageIO hands out the missing half of a truncated JPEG as grey; its error flag is
    what tells, and the command stops before writing anything."""
    image = build("image jpeg", tmp_path, rng)
    image.write_bytes(image.read_bytes()[: image.stat().st_size // 2])
    root = image.parents[1]
    assert "Premature end of JPEG file" in stops_naming(image, fuzz_inputs.read_scene, root)
    out = tmp_path / "out"
    assert main(["train", "--scene", str(root), "--iterations", "1", "--no-progress", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(image) in err[0] and not out.exists()


def test_a_truncated_images_bin_names_the_file(tmp_path, rng):
    """The issue's case: pycolmap ended in "IndexError: Rig with ID ... does not exist"."""
    images = build("colmap bin images", tmp_path, rng)
    images.write_bytes(images.read_bytes()[: images.stat().st_size * 2 // 3])
    assert "truncated" in stops_naming(images, load_scene, images.parents[2])


@pytest.mark.parametrize("count", [2**32, 2**63 - 1])
def test_a_huge_count_in_a_colmap_file_is_refused_before_pycolmap_allocates(tmp_path, rng, count):
    points = build("colmap bin points3D", tmp_path, rng)
    points.write_bytes(struct.pack("<Q", count) + points.read_bytes()[8:])
    assert "more than the file can hold" in stops_naming(points, load_scene, points.parents[2])


def test_a_track_pointing_at_a_missing_observation_is_refused(tmp_path, rng):
    points = build("colmap bin points3D", tmp_path, rng)
    data = bytearray(points.read_bytes())
    track_start = 8 + 51                              # the first point's first (image id, point index)
    data[track_start + 4: track_start + 8] = struct.pack("<i", 10_000)
    points.write_bytes(bytes(data))
    assert "images.bin does not hold" in stops_naming(points, load_scene, points.parents[2])


def test_an_image_name_that_is_not_utf8_is_named(tmp_path, rng):
    """Found by the fuzzer (a flipped byte in images.txt): pycolmap's image name raised UnicodeDecodeError."""
    model = build("colmap txt images", tmp_path, rng)
    images = model.parent / "images.txt" if model.is_file() else model / "images.txt"
    data = images.read_bytes()
    at = data.index("é".encode())
    images.write_bytes(data[:at] + b"\xcd" + data[at + 2:])      # a lead byte followed by no continuation
    assert "not UTF-8" in stops_naming(images, load_scene, images.parents[2])


def test_a_colmap_text_file_cut_within_its_last_line_is_truncated(tmp_path, rng):
    points = build("colmap txt points3D", tmp_path, rng)
    points.write_bytes(points.read_bytes()[:-3])      # a shorter last number still parses
    assert "truncated" in stops_naming(points, load_scene, points.parents[2])


def test_a_camera_size_from_a_damaged_file_is_refused_before_undistortion(tmp_path, rng):
    cameras = build("colmap bin cameras", tmp_path, rng)
    data = bytearray(cameras.read_bytes())
    data[8 + 8: 8 + 16] = struct.pack("<Q", 2**40)   # the first camera's width
    cameras.write_bytes(bytes(data))
    assert "out of range" in stops_naming(cameras, load_scene, cameras.parents[2])


@pytest.mark.parametrize("key, value", [("fl_x", True), ("w", "24"), ("cx", None), ("fl_x", 0.0)])
def test_transforms_numbers_must_be_numbers(tmp_path, rng, key, value):
    import json
    transforms = build("transforms.json (instant-ngp)", tmp_path, rng)
    doc = json.loads(transforms.read_text())
    transforms.write_text(json.dumps(doc | {key: value}))
    stops_naming(transforms, load_scene, transforms.parent)


def test_an_image_header_claiming_an_absurd_size_is_refused_before_decoding(tmp_path, rng):
    image = build("image png", tmp_path, rng)
    data = bytearray(image.read_bytes())
    data[16:24] = struct.pack(">II", 70_000, 1)        # IHDR width and height, and the chunk's CRC to match
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))
    image.write_bytes(bytes(data))
    from dc4gs_cl.scene.images import read_image
    assert "image header says 70000x1" in stops_naming(image, read_image, image)


def test_an_image_that_decodes_beyond_the_memory_available_is_refused_before_training(tmp_path, rng, monkeypatch):
    """A small file that decodes to the pixel cap (2^28 pixels: a PNG of 818 KB trained with 7 GB resident) is
    refused when the scene is read, before any image is decoded, where its decoding needs more than half the memory
    available (here 4 GiB): one line naming the file."""
    import json
    from dc4gs_cl.scene import images
    transforms = build("transforms.json (instant-ngp)", tmp_path, rng)
    doc = json.loads(transforms.read_text())
    image = transforms.parent / doc["frames"][0]["file_path"]
    data = bytearray(image.read_bytes())
    assert data[1:4] == b"PNG"
    data[16:24] = struct.pack(">II", 1 << 14, 1 << 14)   # IHDR: 16384 x 16384, and the chunk's CRC to match
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))
    image.write_bytes(bytes(data))
    monkeypatch.setattr(images, "memory_available", lambda: 4 << 30)
    assert "reading it needs 6.0 GiB" in stops_naming(image, load_scene, transforms.parent)
    assert "more than 50% of the 4.0 GiB" in stops_naming(image, images.read_image, image)


def test_config_values_of_the_wrong_type_are_named(tmp_path, rng):
    import json
    from dc4gs_cl.run_folder import RunFolder
    config = build("config.json", tmp_path, rng)
    doc = json.loads(config.read_text())
    for key, value, says in (("iterations", "700", "iterations: expected int"), ("low_memory", 1, "low_memory"),
                             ("lr_means", float("nan"), "lr_means"), ("save_at", [1.5], "save_at"),
                             ("dc4gs", {"dcc": "yes"}, "dc4gs.dcc"), ("dc4gs", [], "dc4gs"),
                             ("sh_degree", 9, "--sh-degree 9")):
        config.write_text(json.dumps(doc | {key: value}))
        assert says in stops_naming(config, RunFolder(config.parent).read_config)
    config.write_text(json.dumps(doc))
    assert RunFolder(config.parent).read_config().iterations == 700


def test_a_video_whose_metadata_is_no_utf8_stops_with_one_line(tmp_path):
    """The fuzzer's finding: a flipped byte in a stream's metadata made PyAV raise UnicodeDecodeError as it
    opened the video (a traceback); the flip replayed from its seeds."""
    pytest.importorskip("av", reason="the video extra (PyAV) is not installed")
    video = fuzz_inputs.video_input(tmp_path, fuzz_inputs.np.random.default_rng(565280158))
    video.write_bytes(fuzz_inputs.flip(video.read_bytes(), fuzz_inputs.np.random.default_rng(565280207), video))
    assert "cannot decode video ('utf-8' codec can't decode" in stops_naming(video, fuzz_inputs.read_video, video)
