"""Exports of a model for other viewers (`dc4gs-cl export`), and readers of the compact formats that decode
as each format's reference reader does (`render`, `view` and `export` read every format through read_model_file;
the tests and tools/bench_export measure what the quantisation costs). Each compact format's layout is in its
module's docstring:

    ply             the Inria layout (ply.write_ply): float32, lossless
    splat           splat.py: antimatter15/splat, 32 bytes per Gaussian, no SH beyond DC
    spz             spz.py: Niantic's, version 3: gzip of 24-bit positions and 8-bit codes
    compressed-ply  compressed_ply.py: PlayCanvas / SuperSplat: bounds per 256 Gaussians, 4 packed uint32
                    per Gaussian, 8-bit SH

Quantities are the model's: positions in scene units, log scales, unit quaternions (w, x, y, z),
opacity = sigmoid(logit), colour = 0.5 + SH_C0 * f_dc, SH coefficients as stored; "round" is to nearest, and
every code is clamped to its range. Files are little-endian and written atomically (files.py): complete or
not at all. .splat and compressed PLY reorder the Gaussians; the readers return the file's order.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...model import GaussianModel
from ...ply import check_ranges, read_header, read_ply, write_ply
from .compressed_ply import read_compressed_ply, write_compressed_ply
from .splat import read_splat, write_splat
from .spz import read_spz, spz_antialiased, write_spz

FORMATS = {"ply": (".ply", write_ply), "splat": (".splat", write_splat), "spz": (".spz", write_spz),
           "compressed-ply": (".compressed.ply", write_compressed_ply)}
READERS = {"ply": read_ply, "splat": read_splat, "spz": read_spz, "compressed-ply": read_compressed_ply}


def export_format(path: str | os.PathLike, fmt: str | None = None) -> str:
    """The format named, or else the one whose suffix ends the file name (the longest that does)."""
    if fmt is not None:
        if fmt not in FORMATS:
            raise InputError(path, f"unknown export format {fmt!r} (known: {', '.join(FORMATS)})")
        return fmt
    name = Path(path).name.lower()
    for fmt, (suffix, _) in sorted(FORMATS.items(), key=lambda item: -len(item[1][0])):
        if name.endswith(suffix):
            return fmt
    raise InputError(path, "unknown export format: name the file "
                           f"{', '.join(suffix for suffix, _ in FORMATS.values())} or give the format")


def read_model_file(path: str | os.PathLike) -> GaussianModel:
    """A model from a file of any format `export` writes, told by its name (.splat, .spz, .compressed.ply; any
    other name is a PLY: the Inria layout, or a compressed PLY where it holds a chunk element). InputError (one
    line naming the file) for a file of none of them, an empty model, NaN or Inf, or values beyond what the
    kernels keep finite."""
    name = Path(path).name.lower()
    fmt = next((f for f in ("splat", "spz", "compressed-ply") if name.endswith(FORMATS[f][0])), "ply")
    if fmt == "ply" and _has_chunks(path):
        fmt = "compressed-ply"
    model = READERS[fmt](path)
    if len(model) == 0:
        raise InputError(path, "no Gaussians")
    bad = sum(int((~np.isfinite(a)).sum()) for a in (model.means, model.log_scales, model.quats, model.sh))
    if bad:   # .splat's raw floats, a scale read as 0 (log -inf)
        raise InputError(path, f"{bad} NaN or Inf values")
    check_ranges(path, model)
    return model


def recorded_antialiased(path: str | os.PathLike) -> bool | None:
    """The rasterization mode a model file records: a .spz's header flag; None for the formats that have no place
    for it (PLY, .splat, compressed PLY)."""
    return spz_antialiased(path) if Path(path).name.lower().endswith(FORMATS["spz"][0]) else None


def _has_chunks(path) -> bool:
    try:
        with open(path, "rb") as f:
            _, elements = read_header(path, f)
    except OSError as e:
        raise InputError(path, f"cannot read: {e.strerror or e}") from None
    return any(e["name"] == "chunk" for e in elements)


def export_model(model: GaussianModel, path: str | os.PathLike, fmt: str | None = None,
                 antialiased: bool = False) -> None:
    """Write `model` to `path` in `fmt` (default: by the file name); antialiased: the model trained so, which .spz
    records (the other formats cannot). Atomic: the file appears complete or not at all; an unwritable path raises
    OutputError, an unknown format or an empty model InputError."""
    fmt = export_format(path, fmt)
    if len(model) == 0:
        raise InputError(path, "no Gaussians to export")
    check_ranges(path, model)   # (a model read from a PLY was checked there) no format then holds an Inf
    if fmt == "spz":
        write_spz(Path(path), model, antialiased)
    else:
        FORMATS[fmt][1](Path(path), model)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of `dc4gs-cl export` (run by cmd_export)."""
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--model", type=Path, help="a training output folder: its last saved model (or --iteration)")
    source.add_argument("--ply", type=Path, help="a standard 3DGS PLY")
    p.add_argument("--iteration", type=int, default=None,
                   help="with --model: which saved iteration (default: the last)")
    p.add_argument("--out", type=Path, required=True,
                   help="the file to write; its name gives the format (" +
                        ", ".join(suffix for suffix, _ in FORMATS.values()) + ") unless --format does")
    p.add_argument("--format", choices=list(FORMATS), default=None,
                   help="ply (lossless), splat (antimatter15, no SH), spz (Niantic) or compressed-ply (PlayCanvas)")


def cmd_export(args) -> int:
    # here, not at the top: model_source reads through this package's readers
    from ..model_source import ModelSource

    if args.iteration is not None and args.model is None:
        raise InputError(None, "--iteration needs --model")
    fmt = export_format(args.out, args.format)   # a bad name fails before the model is read
    if args.model is not None:
        if not args.model.is_dir():
            raise InputError(args.model, "no such training output folder")
        source = ModelSource.of_run(args.model, args.iteration, settings_optional=True)
    else:
        source = ModelSource.of_file(args.ply)
    model, antialiased = source.model, bool(source.antialiased)
    export_model(model, args.out, fmt, antialiased)
    print(f"{fmt}: {len(model):,} Gaussians, {args.out.stat().st_size:,} bytes written to {args.out}")
    if antialiased and fmt != "spz":   # the viewers would render it without its compensation
        print(f"the run trained --antialiased, which a {fmt} file cannot record: render it with --antialiased "
              "(.spz records it)")
    return 0
