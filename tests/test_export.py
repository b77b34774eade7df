"""Exports (dc4gs_cl.apps.export): every format read back within its own quantisation bounds, each derived
from the format's layout (the docstrings of dc4gs_cl/apps/export/*.py); the .splat order and size; the files
read by a tool nobody here wrote: PlayCanvas's splat-transform, whose .spz reader and writer are Niantic's
own library (skipped with the reason when it is not installed); bad input and unwritable output."""
import argparse
import gzip
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from dc4gs_cl.apps import export
from dc4gs_cl.apps.export import FORMATS, READERS, export_model
from dc4gs_cl.apps.export.common import SMALLEST_THREE_BITS, SQRT_HALF, dc_colour, unit_quats
from dc4gs_cl.apps.export.compressed_ply import CHUNK_SIZE, COLOR_BITS, LOG_SCALE_LIMIT, SH_SPAN, XYZ_BITS, morton_order
from dc4gs_cl.apps.export.splat import SPLAT_RECORD, read_splat
from dc4gs_cl.apps.export.spz import (SPZ_COLOR_SCALE, SPZ_FRACTIONAL_BITS, SPZ_ROTATION_MAX, SPZ_SCALE_OFFSET,
                                      SPZ_SCALE_STEPS, SPZ_SH_BUCKETS, SPZ_SH_STEPS, read_spz)
from dc4gs_cl.errors import InputError, OutputError
from dc4gs_cl.model import GaussianModel
from dc4gs_cl.ply import read_ply, write_ply
from dc4gs_cl.run_folder import RunFolder
from dc4gs_cl.reference.testing import random_model

N = 1500            # Gaussians per model: several compressed-PLY chunks, the last one partial
F32 = float(np.finfo(np.float32).eps)
BYTE = 1 / 255      # one step of an 8-bit [0, 1] code
SPLAT_TRANSFORM_ENV = "DC4GS_SPLAT_TRANSFORM"
SPLAT_TRANSFORM_CACHE = Path.home() / ".cache" / "dc4gs-cl" / "splat-transform"
SPLAT_TRANSFORM_INSTALL = f"npm install --prefix {SPLAT_TRANSFORM_CACHE} @playcanvas/splat-transform@2.7.1"
COMPACT = ["splat", "spz", "compressed-ply"]


def model_for(rng, degree, external=False):
    """Random Gaussians in [-3, 3]^3. For the external readers opacities stay off 0 and 1: a code of 0 or
    255 decodes to a logit of -inf or inf there, which a standard PLY (and read_ply) cannot hold."""
    m = random_model(rng, N, degree, spread=3.0)
    if external:
        m.opacity_logits[:] = np.clip(m.opacity_logits, -5.0, 5.0)
    return m


def written(tmp_path, model, fmt) -> Path:
    path = tmp_path / f"model{FORMATS[fmt][0]}"
    export_model(model, path)
    return path


def file_order(fmt, model) -> np.ndarray:
    """Where each Gaussian of the file comes from: .splat sorts by size times opacity (largest first, as
    antimatter15's converter), compressed PLY by Morton code, the others keep the model's order."""
    if fmt == "splat":
        key = np.exp(model.log_scales.astype(np.float64)).prod(axis=1) * model.opacities
        return np.argsort(-key, kind="stable")
    return morton_order(model.means) if fmt == "compressed-ply" else np.arange(len(model))


def check(name, got, want, bound):
    """|got - want| <= bound, plus float32 rounding in the reader: Niantic's decodes in float32, with
    intermediates up to about 1 and divisions by 0.15 (8 ulps of max(|want|, 1) covers that)."""
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    err = np.abs(got - want) - (bound + 8 * F32 * np.maximum(np.abs(want), 1.0))
    assert np.all(err <= 0), f"{name}: error beyond the bound by up to {err.max():.3g}"


def chunk_steps(values, bits, limit=np.inf):
    """Half a code step of each value's chunk bounds: (max - min) / (2 (2^b - 1)) per axis."""
    v = values.astype(np.float64)
    lo = np.clip(np.minimum.reduceat(v, np.arange(0, len(v), CHUNK_SIZE)), -limit, limit)
    hi = np.clip(np.maximum.reduceat(v, np.arange(0, len(v), CHUNK_SIZE)), -limit, limit)
    return np.repeat((hi - lo) / (2 * ((1 << np.array(bits)) - 1)), CHUNK_SIZE, axis=0)[:len(v)]


def smallest_three_bound(eps):
    """Quaternion distance when each of the three smaller components is off by at most eps and the largest
    (at least 1/2) is rebuilt from them: it moves by at most sum|c_i| eps / L <= 3 eps to first order, so
    the distance is at most sqrt(3 + 9) eps; 1% covers the second-order terms."""
    return np.sqrt(12.0) * eps * 1.01


def check_quats(name, got, want, bound):
    q, w = unit_quats(got), unit_quats(want)
    q *= np.where((q * w).sum(axis=1) < 0, -1.0, 1.0)[:, None]   # q and -q are one rotation
    check(name, np.linalg.norm(q - w, axis=1), 0.0, bound)


def assert_within_bounds(fmt, model, back, splat_rotation_step=0.5 / 128):
    """`back` (read from a file of `fmt`) against `model`: each field within the format's quantisation
    error. splat_rotation_step: how far a reader's decoded rotation byte lies from the true component."""
    m = model
    sh = m.sh.astype(np.float64)
    colour, back_colour = dc_colour(sh[:, 0]), dc_colour(back.sh[:, 0])
    assert len(back) == len(m)
    check("opacity", back.opacities, m.opacities, 0.5 * BYTE)   # every compact format: round(255 opacity)
    if fmt == "splat":
        assert back.sh_degree == 0
        check("means", back.means, m.means, 0.0)
        check("log scales", back.log_scales, m.log_scales, F32)
        check("colour", back_colour, np.clip(colour, 0, 1), 0.5 * BYTE)
        # Each component is off by at most splat_rotation_step, or by 1/128 where 128 q + 128 reached 256
        # and was clamped to 255 (that component is then > 0.996 and the others small): the error vector
        # is at most 2 x the largest of those; normalising at most doubles the distance.
        check_quats("rotation", back.quats, m.quats, 4 * max(splat_rotation_step, 1 / 128))
    elif fmt == "spz":
        assert back.sh_degree == m.sh_degree
        check("means", back.means, m.means, 2.0 ** -(SPZ_FRACTIONAL_BITS + 1))
        top = 255 / SPZ_SCALE_STEPS - SPZ_SCALE_OFFSET
        check("log scales", back.log_scales, np.clip(m.log_scales, -SPZ_SCALE_OFFSET, top), 0.5 / SPZ_SCALE_STEPS)
        dc_limit = 0.5 / SPZ_COLOR_SCALE
        check("f_dc", back.sh[:, 0], np.clip(sh[:, 0], -dc_limit, dc_limit), 0.5 * BYTE / SPZ_COLOR_SCALE)
        # round(128 c) (half a step), then to the nearest multiple of the bucket (half a bucket)
        rest = m.sh.shape[1] - 1
        bucket = np.where(np.arange(rest) < 3, *SPZ_SH_BUCKETS)[None, :, None]
        check("SH rest", back.sh[:, 1:], np.clip(sh[:, 1:], -1, 127 / SPZ_SH_STEPS), (0.5 + bucket / 2) / SPZ_SH_STEPS)
        check_quats("rotation", back.quats, m.quats, smallest_three_bound(SQRT_HALF * 0.5 / SPZ_ROTATION_MAX))
    else:
        assert back.sh_degree == m.sh_degree
        check("means", back.means, m.means, chunk_steps(m.means, XYZ_BITS))
        check("log scales", back.log_scales, m.log_scales, chunk_steps(m.log_scales, XYZ_BITS, LOG_SCALE_LIMIT))
        check("colour", back_colour, colour, chunk_steps(colour, COLOR_BITS[:3]))
        # floor(256 (c / 8 + 0.5)): read at the code's centre (half a step), the end codes at +-4 (a step)
        c = np.clip(sh[:, 1:], -SH_SPAN / 2, SH_SPAN / 2)
        inner = np.abs(c) < SH_SPAN / 2 - SH_SPAN / 256
        check("SH rest", back.sh[:, 1:], c, np.where(inner, SH_SPAN / 512, SH_SPAN / 256))
        check_quats("rotation", back.quats, m.quats,
                    smallest_three_bound(0.5 / ((1 << SMALLEST_THREE_BITS[1]) - 1) / SQRT_HALF))


# our readers -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("degree", range(4))
@pytest.mark.parametrize("fmt", COMPACT)
def test_read_back_within_the_quantisation_bounds(tmp_path, rng, fmt, degree):
    m = model_for(rng, degree)
    path = written(tmp_path, m, fmt)
    order = file_order(fmt, m)
    assert np.array_equal(np.sort(order), np.arange(N))
    assert_within_bounds(fmt, reordered(m, order), READERS[fmt](path))


def reordered(m, order):
    return GaussianModel(m.means[order], m.log_scales[order], m.quats[order], m.opacity_logits[order], m.sh[order])


def test_ply_export_is_the_lossless_ply(tmp_path, rng):
    m = model_for(rng, 3)
    export_model(m, tmp_path / "a.ply")
    write_ply(tmp_path / "b.ply", m)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


def test_splat_is_32_bytes_a_gaussian_sorted_by_size_times_opacity(tmp_path, rng):
    m = model_for(rng, 2)
    path = written(tmp_path, m, "splat")
    assert path.stat().st_size == 32 * N
    # positions are stored exactly, so they tell where each record came from
    order = file_order("splat", m)
    assert np.array_equal(read_splat(path).means, m.means[order])
    rec = np.frombuffer(path.read_bytes(), SPLAT_RECORD)   # codes: rounded, so within half a code
    rgba = np.concatenate([dc_colour(m.sh[order, 0]), m.opacities[order, None]], axis=1)
    check("RGBA codes", rec["rgba"], np.clip(255 * rgba, 0, 255), 0.5)
    check("rotation codes", rec["rotation"], np.minimum(128 * unit_quats(m.quats[order]) + 128, 255), 0.5)


def test_spz_header_and_coordinates(tmp_path, rng):
    """Version 3, gzip; positions stored right-up-back: y and z negated."""
    m = model_for(rng, 1)
    data = gzip.decompress(written(tmp_path, m, "spz").read_bytes())
    magic, version, count = np.frombuffer(data[:12], "<u4")
    assert (magic, version, count) == (0x5053474E, 3, N) and tuple(data[12:16]) == (1, 12, 0, 0)
    b = np.frombuffer(data[16:25], np.uint8).reshape(3, 3).astype(np.int64)   # the first Gaussian's x, y, z
    fixed = ((b[:, 0] | b[:, 1] << 8 | b[:, 2] << 16) ^ 0x800000) - 0x800000
    check("stored first position", fixed / 2.0 ** 12, m.means[0] * [1, -1, -1], 2.0 ** -13)


def spz_variant(tmp_path, rng, edit, trailer: bytes = b""):
    """A one-Gaussian .spz whose inflated data edit(bytearray) changed, gzipped again (trailer: bytes after it)."""
    path = written(tmp_path, model_for(rng, 1), "spz")
    data = bytearray(gzip.decompress(path.read_bytes()))
    edit(data)
    path.write_bytes(gzip.compress(bytes(data), mtime=0) + trailer)
    return path


@pytest.mark.parametrize("case, says", [
    ("inflates past its data", "data past the"), ("a second gzip member", "data past the"),
    ("fractional bits 255", "fractional bits 255"), ("20 million promised", "DC4GS_MAX_READ_GAUSSIANS")])
def test_spz_bombs_are_refused_before_they_take_memory(tmp_path, rng, case, says):
    """A 2 MB .spz inflating to 2 GiB took 4.3 GB and 69 s (the trailing data then ignored); one promising 20
    million Gaussians 7.7 GB; fractional bits 255 put every Gaussian at the origin: one line each, and the read
    never holds more than a few MB (the trailing 256 MiB of zeros are never inflated)."""
    import tracemalloc
    if case == "inflates past its data":
        path = spz_variant(tmp_path, rng, lambda d: d.extend(bytes(1 << 28)))
    elif case == "a second gzip member":
        path = spz_variant(tmp_path, rng, lambda d: None, gzip.compress(b"more", mtime=0))
    elif case == "fractional bits 255":
        path = spz_variant(tmp_path, rng, lambda d: d.__setitem__(13, 255))
    else:
        path = spz_variant(tmp_path, rng, lambda d: d.__setitem__(slice(8, 12), (20_000_001).to_bytes(4, "little")))
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=says):
            READERS["spz"](path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20, peak


def test_spz_count_cap_is_raised_by_the_environment(tmp_path, rng, monkeypatch):
    path = spz_variant(tmp_path, rng, lambda d: d.__setitem__(slice(8, 12), (20_000_001).to_bytes(4, "little")))
    monkeypatch.setenv("DC4GS_MAX_READ_GAUSSIANS", "30000000")
    with pytest.raises(InputError, match="truncated"):   # past the cap: read as far as the data goes
        READERS["spz"](path)
    monkeypatch.setenv("DC4GS_MAX_READ_GAUSSIANS", "lots")
    with pytest.raises(InputError, match="DC4GS_MAX_READ_GAUSSIANS='lots': expected a count"):
        READERS["spz"](path)


def test_spz_fewer_fractional_bits_for_far_gaussians(tmp_path, rng):
    m = model_for(rng, 0)
    m.means[0] = [5000.0, -3000.0, 0.5]        # beyond the 2048 units of 12 fractional bits
    back = read_spz(written(tmp_path, m, "spz"))
    assert gzip.decompress((tmp_path / "model.spz").read_bytes())[13] == 10
    check("means", back.means, m.means, 2.0 ** -11)


def test_compressed_ply_chunks_hold_256_neighbours(tmp_path, rng):
    m = model_for(rng, 0)
    data = written(tmp_path, m, "compressed-ply").read_bytes()
    header = data[:data.index(b"end_header\n")].decode()
    assert f"element chunk {-(-N // CHUNK_SIZE)}" in header and f"element vertex {N}" in header
    assert "element sh" not in header
    # Morton order on a shuffled 16^3 grid: each run of 256 fills an 8 x 8 x 4 block
    grid = np.stack(np.meshgrid(*[np.arange(16.0)] * 3), axis=-1).reshape(-1, 3)
    grid = grid[rng.permutation(len(grid))]
    runs = grid[morton_order(grid)].reshape(-1, CHUNK_SIZE, 3)
    assert sorted(np.ptp(runs, axis=1)[0]) == [3, 7, 7] and len(np.unique(np.ptp(runs, axis=1), axis=0)) == 1


# a reader (and writer) nobody here wrote ------------------------------------------------------------------
@pytest.fixture(scope="session")
def splat_transform() -> str:
    """PlayCanvas's splat-transform CLI: $DC4GS_SPLAT_TRANSFORM, else on PATH, else in the cache folder."""
    cached = SPLAT_TRANSFORM_CACHE / "node_modules" / ".bin" / "splat-transform"
    tool = os.environ.get(SPLAT_TRANSFORM_ENV) or shutil.which("splat-transform") or (
        str(cached) if cached.exists() else None)
    if tool is None:
        pytest.skip(f"splat-transform not found (${SPLAT_TRANSFORM_ENV}, PATH, {cached}); install it (node >= 18) "
                    f"with: {SPLAT_TRANSFORM_INSTALL}")
    return tool


def convert(tool, src: Path, dst: Path, *options):
    r = subprocess.run([tool, "-q", "-w", *options, str(src), str(dst)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, f"splat-transform failed on {src.name}: {r.stderr.strip()}"


@pytest.mark.parametrize("fmt", COMPACT)
def test_splat_transform_reads_our_files(tmp_path, rng, splat_transform, fmt):
    """splat-transform turns our file into a standard PLY; that PLY is our model within the format's bounds.
    Its .splat reader decodes a rotation byte as u / 127.5 - 1, up to 1.5 / 128 from the true component."""
    m = model_for(rng, 3, external=True)
    convert(splat_transform, written(tmp_path, m, fmt), tmp_path / "back.ply")
    assert_within_bounds(fmt, reordered(m, file_order(fmt, m)), read_ply(tmp_path / "back.ply"),
                         splat_rotation_step=1.5 / 128)


def test_spz_is_what_niantics_writer_writes(tmp_path, rng, splat_transform):
    """Niantic's writer (in splat-transform) on the same model: every value within one code of ours (float32
    rounding there can tip a value that lies on a rounding boundary)."""
    m = model_for(rng, 3)
    write_ply(tmp_path / "model.ply", m)
    convert(splat_transform, tmp_path / "model.ply", tmp_path / "theirs.spz", "--spz-version", "3")
    ours, theirs = read_spz(written(tmp_path, m, "spz")), read_spz(tmp_path / "theirs.spz")
    check("means", ours.means, theirs.means, 2.0 ** -SPZ_FRACTIONAL_BITS)
    check("log scales", ours.log_scales, theirs.log_scales, 1 / SPZ_SCALE_STEPS)
    check("opacity", ours.opacities, theirs.opacities, BYTE)
    check("f_dc", ours.sh[:, 0], theirs.sh[:, 0], BYTE / SPZ_COLOR_SCALE)
    check("SH rest", ours.sh[:, 1:], theirs.sh[:, 1:], max(SPZ_SH_BUCKETS) / SPZ_SH_STEPS)
    check_quats("rotation", ours.quats, theirs.quats, smallest_three_bound(SQRT_HALF / SPZ_ROTATION_MAX))


# bad input, unwritable output ------------------------------------------------------------------------------
def run_cli(*argv):
    p = argparse.ArgumentParser()
    export.add_arguments(p)
    return export.cmd_export(p.parse_args([str(a) for a in argv]))


def test_cli_exports_a_run_and_says_what_it_wrote(tmp_path, rng, capsys):
    m = model_for(rng, 1)
    RunFolder(tmp_path / "run").save_model(700, m)
    out = tmp_path / "out" / "scene.spz"
    assert run_cli("--model", tmp_path / "run", "--out", out) == 0
    assert capsys.readouterr().out.strip() == f"spz: {N:,} Gaussians, {out.stat().st_size:,} bytes written to {out}"
    assert run_cli("--model", tmp_path / "run", "--iteration", 700, "--out", out, "--format", "splat") == 0
    assert out.stat().st_size == 32 * N


def test_cli_refuses_an_output_that_is_not_a_regular_file(tmp_path, rng, capsys):
    """`export --out /dev/full` printed "bytes written" and replaced the device node (a FIFO stands in for it)."""
    import stat
    RunFolder(tmp_path / "run").save_model(700, model_for(rng, 1))
    fifo = tmp_path / "fifo.splat"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match="is a FIFO, not a regular file"):   # one line, exit 2 (cli.py)
        run_cli("--model", tmp_path / "run", "--out", fifo)
    assert "bytes written" not in capsys.readouterr().out and stat.S_ISFIFO(os.lstat(fifo).st_mode)


@pytest.mark.parametrize("source", ["--model", "--ply"])
def test_missing_source_names_its_path(tmp_path, source):
    missing = tmp_path / "nowhere"
    with pytest.raises(InputError) as e:
        run_cli(source, missing, "--out", tmp_path / "x.splat")
    assert str(missing) in str(e.value)
    assert not (tmp_path / "x.splat").exists()


def test_run_without_that_iteration(tmp_path, rng):
    RunFolder(tmp_path).save_model(10, model_for(rng, 0))
    with pytest.raises(InputError, match="no model saved at iteration 11"):
        run_cli("--model", tmp_path, "--iteration", 11, "--out", tmp_path / "x.spz")
    with pytest.raises(InputError, match="--iteration needs --model"):
        run_cli("--ply", tmp_path / "a.ply", "--iteration", 11, "--out", tmp_path / "x.spz")


def test_unknown_format(tmp_path, rng):
    m = model_for(rng, 0)
    for path, fmt in ((tmp_path / "model.xyz", None), (tmp_path / "model.ply", "obj")):
        with pytest.raises(InputError) as e:
            export_model(m, path, fmt)
        assert e.value.path == str(path)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_unwritable_output_leaves_nothing(tmp_path, rng, fmt):
    m = model_for(rng, 1)
    folder = tmp_path / f"folder{FORMATS[fmt][0]}"
    folder.mkdir()
    with pytest.raises(OutputError) as e:
        export_model(m, folder)
    assert e.value.path == str(folder)
    assert [p.name for p in tmp_path.iterdir()] == [folder.name] and not list(folder.iterdir())


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_no_export_of_values_beyond_what_stays_finite(tmp_path, rng, fmt):
    """A model whose log scale overflows float32 once exponentiated (a .splat held inf) is refused before
    anything is written, naming the Gaussian (a PLY with one is refused when read)."""
    m = model_for(rng, 1)
    m.log_scales[2, 0] = 1e30
    path = tmp_path / f"model{FORMATS[fmt][0]}"
    with pytest.raises(InputError) as e:
        export_model(m, path)
    assert e.value.path == str(path) and "log scale beyond" in str(e.value) and "Gaussian 2:" in str(e.value)
    assert not list(tmp_path.iterdir())


def test_output_inside_a_file(tmp_path, rng):
    (tmp_path / "file").write_bytes(b"")
    with pytest.raises(OutputError):
        export_model(model_for(rng, 0), tmp_path / "file" / "x.splat")


def test_failed_write_keeps_the_previous_file(tmp_path, rng, monkeypatch):
    """A disk that fills up mid-write: OutputError, the earlier export intact, no temporary file."""
    out = tmp_path / "model.spz"
    export_model(model_for(rng, 0), out)
    before = out.read_bytes()

    def full(fd):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OutputError, match="No space left"):
        export_model(model_for(rng, 0), out)
    assert out.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["model.spz"]


# render and view read every format -------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", list(FORMATS))
def test_render_reads_every_export_format(tmp_path, rng, fmt):
    """`render --ply FILE` (and `view FILE`, through the same read_model_file) takes each format export writes:
    the renders of a compact file are those of its model read back; a compressed PLY is told by its elements
    whatever its name."""
    from dc4gs_cl.apps.export import read_model_file
    from dc4gs_cl.cli import main
    from dc4gs_cl.scene.images import read_image
    m = random_model(rng, 800, 1, spread=1.5)
    path = written(tmp_path, m, fmt)
    if fmt == "compressed-ply":
        path = path.rename(tmp_path / "plain-looking.ply")
    back = READERS[fmt](path)
    model = read_model_file(path)
    assert all(np.array_equal(getattr(model, k), getattr(back, k)) for k in ("means", "log_scales", "quats", "sh"))
    write_ply(tmp_path / "back.ply", back)
    for name, source in (("file", path), ("back", tmp_path / "back.ply")):
        assert main(["render", "--ply", str(source), "--out", str(tmp_path / name), "-r", "4"]) == 0
    for png in (tmp_path / "back" / "test" / "renders").glob("*.png"):
        assert np.array_equal(read_image(png), read_image(tmp_path / "file" / "test" / "renders" / png.name))


@pytest.mark.parametrize("name,data,says", [
    ("bad.spz", b"\x1f\x8b" + b"\x00" * 30, "not a .spz file"),
    ("bad.splat", b"\x00" * 33, "not a .splat file"),
    ("nan.splat", np.array([(np.nan, 1.0, 1.0)], np.float32).tobytes() + b"\x00" * 20, "NaN or Inf"),
    ("bad.compressed.ply", b"ply\nformat ascii 1.0\nend_header\n", "not a compressed PLY"),
    ("model.bin", b"nothing", "not a PLY file"),
])
def test_render_of_a_bad_model_file_is_one_line(tmp_path, capsys, name, data, says):
    from dc4gs_cl.cli import main
    path = tmp_path / name
    path.write_bytes(data)
    assert main(["render", "--ply", str(path), "--out", str(tmp_path / "out"), "-r", "8"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and says in err[0], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("fmt, line, huge", [
    ("compressed-ply", b"element chunk ", 10**12), ("compressed-ply", b"element vertex ", 4 * 10**9),
    ("compressed-ply", b"element sh ", 10**20), ("ply", b"element vertex ", 4 * 10**9),
    ("ply", b"element vertex ", 10**20)])
def test_ply_headers_promising_more_rows_than_the_file_holds_are_one_line(tmp_path, rng, fmt, line, huge):
    """`element chunk 1000000000000`, `element vertex 4000000000` or `element sh 99999999999999999999` in a
    compressed PLY ended in MemoryError or OverflowError: every element of every PLY format is checked against the
    file's bytes before anything is sized by it."""
    m = model_for(rng, 1)
    path = tmp_path / f"model{FORMATS[fmt][0]}"
    export_model(m, path, fmt)
    data = path.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    if line not in head:   # a compressed PLY of degree 0 has no sh element: add one
        head += line + b"1\nproperty uchar f_rest_0\n"
    start = head.index(line) + len(line)
    head = head[:start] + str(huge).encode() + head[head.index(b"\n", start):]
    path.write_bytes(head + b"end_header\n" + body)
    with pytest.raises(InputError, match="truncated: the header promises"):
        READERS[fmt](path)
