"""The 3DGS PLY: exact round trips, the Inria header, channel-major f_rest, tolerant reading, clear errors,
atomic writes."""
import os

import numpy as np
import pytest

from dc4gs_cl import ply
from dc4gs_cl.errors import InputError, OutputError
from dc4gs_cl.model import GaussianModel
from dc4gs_cl.ply import read_ply, write_ply

FIELDS = ("means", "log_scales", "quats", "opacity_logits", "sh")
NP_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
            "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1", "float32": "f4", "float64": "f8"}


def random_model(rng, n, degree):
    k = (degree + 1) ** 2
    return GaussianModel(rng.normal(size=(n, 3)) * 10, rng.normal(size=(n, 3)), rng.normal(size=(n, 4)),
                         rng.normal(size=n) * 5, rng.normal(size=(n, k, 3)))


def assert_same(a, b):
    """Bit-exact: also tells -0.0 from 0.0."""
    for field in FIELDS:
        x, y = getattr(a, field), getattr(b, field)
        assert x.shape == y.shape and x.dtype == y.dtype == np.float32, field
        np.testing.assert_array_equal(x.view(np.uint32), y.view(np.uint32), err_msg=field)


def columns(model):
    """The model as named PLY columns (f_rest channel-major), to write in any order with write_custom."""
    cols = {"x": model.means[:, 0], "y": model.means[:, 1], "z": model.means[:, 2],
            "opacity": model.opacity_logits}
    for i in range(3):
        cols[f"f_dc_{i}"] = model.sh[:, 0, i]
        cols[f"scale_{i}"] = model.log_scales[:, i]
    for i in range(4):
        cols[f"rot_{i}"] = model.quats[:, i]
    rest = model.sh.shape[1] - 1
    for i in range(3 * rest):
        cols[f"f_rest_{i}"] = model.sh[:, 1 + i % rest, i // rest]
    return cols


def write_custom(path, elements, fmt="binary_little_endian", header_extra=()):
    """A PLY from [(element name, count, [(type, name, values)])]; type "list uchar int" makes a list
    property whose values are sequences."""
    order = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": None}[fmt]
    head = ["ply", f"format {fmt} 1.0", "comment written by test_ply", *header_extra]
    body = []
    for name, count, props in elements:
        head.append(f"element {name} {count}")
        head += [f"property {t} {pname}" for t, pname, _ in props]
        for r in range(count):
            fields = []
            for t, _, values in props:
                if t.startswith("list"):
                    _, lt, vt = t.split()
                    fields += [(lt, len(values[r]))] + [(vt, v) for v in values[r]]
                else:
                    fields.append((t, values[r]))
            if order is None:
                body.append((" ".join(repr(float(v)) if NP_TYPES[t][0] == "f" else str(int(v))
                                      for t, v in fields) + "\n").encode())
            else:
                body.append(b"".join(np.array(v, dtype=order + NP_TYPES[t]).tobytes() for t, v in fields))
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\nend_header\n").encode() + b"".join(body))


def vertex(model, types=None, order=None, extra=()):
    """The vertex element of `model` for write_custom: property types by name (default float), order."""
    cols = columns(model)
    names = order or list(cols)
    return ("vertex", len(model), [((types or {}).get(n, "float"), n, cols[n]) for n in names] + list(extra))


@pytest.fixture
def rng():
    seed = np.random.SeedSequence().entropy
    print(f"seed {seed}")
    return np.random.default_rng(seed)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_is_bit_exact(tmp_path, rng, degree):
    model = random_model(rng, 1000, degree)
    model.sh[0, 0] = [-0.0, np.float32(1e-45), np.finfo(np.float32).max]  # sign of zero, subnormal, max
    write_ply(tmp_path / "a.ply", model)
    back = read_ply(tmp_path / "a.ply")
    assert back.sh_degree == degree
    assert_same(model, back)
    assert os.listdir(tmp_path) == ["a.ply"]


def test_header_is_what_plyfile_writes(tmp_path, rng):
    model = random_model(rng, 7, 3)
    write_ply(tmp_path / "a.ply", model)
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(45)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 7\n"
    header += "".join(f"property float {n}\n" for n in names) + "end_header\n"
    data = (tmp_path / "a.ply").read_bytes()
    assert data[:len(header)] == header.encode("ascii")
    assert len(data) == len(header) + 7 * 62 * 4
    table = np.frombuffer(data[len(header):], dtype="<f4").reshape(7, 62)
    np.testing.assert_array_equal(table[:, 3:6], 0)  # normals
    np.testing.assert_array_equal(table[:, 54], model.opacity_logits)
    np.testing.assert_array_equal(table[:, 58:62], model.quats)  # w x y z


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_f_rest_is_channel_major(tmp_path, degree):
    k = (degree + 1) ** 2
    sh = np.zeros((2, k, 3))
    for coef in range(k):
        for channel in range(3):
            sh[:, coef, channel] = 100 * coef + channel
    model = GaussianModel(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 4)), np.zeros(2), sh)
    write_ply(tmp_path / "a.ply", model)
    data = (tmp_path / "a.ply").read_bytes()
    table = np.frombuffer(data[data.index(b"end_header\n") + 11:], dtype="<f4").reshape(2, -1)
    np.testing.assert_array_equal(table[0, 6:9], [0, 1, 2])  # f_dc_0..2 = R, G, B of coefficient 0
    rest = table[0, 9:9 + 3 * (k - 1)]
    for i, value in enumerate(rest):  # f_rest_i = channel * (K-1) + coef - 1
        channel, coef = divmod(i, k - 1)
        assert value == 100 * (coef + 1) + channel, i
    assert_same(model, read_ply(tmp_path / "a.ply"))


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian", "ascii"])
def test_reads_other_layouts(tmp_path, rng, fmt):
    """Shuffled properties, other numeric types, extra properties, extra elements before and after."""
    model = random_model(rng, 40, 2)
    model.opacity_logits[:] = rng.integers(-300, 300, 40)  # stored as short below
    names = list(columns(model))
    rng.shuffle(names)
    types = {"x": "double", "f_rest_3": "float64", "opacity": "short", "rot_2": "float32"}
    faces = [list(rng.integers(0, 40, rng.integers(0, 5))) for _ in range(6)]
    extra = [("uchar", "red", rng.integers(0, 256, 40)), ("float", "nx", np.zeros(40))]
    elements = [
        ("camera", 2, [("float", "fx", [1.0, 2.0]), ("int", "w", [640, 480])]),
        ("face", 6, [("list uchar int", "vertex_indices", faces), ("uint", "flags", range(6))]),
        vertex(model, types, names, extra),
        ("edge", 3, [("int", "a", [1, 2, 3]), ("list ushort uint", "b", [[1], [], [4, 5]])]),
    ]
    write_custom(tmp_path / "a.ply", elements, fmt, header_extra=["obj_info made by hand"])
    assert_same(model, read_ply(tmp_path / "a.ply"))


def test_reads_crlf_header(tmp_path, rng):
    model = random_model(rng, 5, 0)
    write_ply(tmp_path / "a.ply", model)
    data = (tmp_path / "a.ply").read_bytes()
    end = data.index(b"end_header\n") + 11
    (tmp_path / "b.ply").write_bytes(data[:end].replace(b"\n", b"\r\n") + data[end:])
    assert_same(model, read_ply(tmp_path / "b.ply"))


def bad_file(tmp_path, rng, case):
    """Write one kind of bad file; return its path and a phrase the error must contain."""
    path = tmp_path / f"{case}.ply"
    model = random_model(rng, 10, 1)
    good = vertex(model)
    if case == "missing":
        return path, "No such file"
    if case == "directory":
        path.mkdir()
        return path, "cannot read"
    if case == "magic":
        path.write_bytes(b"PK\x03\x04 not a ply at all")
        return path, "not a PLY"
    if case == "empty file":
        path.write_bytes(b"")
        return path, "not a PLY"
    if case == "no end_header":
        path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n")
        return path, "end_header"
    if case == "bad count":
        write_custom(path, [good])
        path.write_bytes(path.read_bytes().replace(b"element vertex 10", b"element vertex ten"))
        return path, "element vertex ten"
    if case == "bad type":
        write_custom(path, [good])
        path.write_bytes(path.read_bytes().replace(b"property float x\n", b"property half x\n"))
        return path, "property half x"
    if case == "bad format":
        write_custom(path, [good])
        path.write_bytes(path.read_bytes().replace(b"binary_little_endian", b"binary_middle_endian"))
        return path, "format binary_middle_endian"
    if case == "no vertex":
        write_custom(path, [("face", 0, [("list uchar int", "vertex_indices", [])])])
        return path, "no 'vertex' element"
    if case == "missing properties":
        keep = [p for p in good[2] if p[1] not in ("opacity", "rot_3")]
        write_custom(path, [("vertex", 10, keep)])
        return path, "missing vertex properties: opacity rot_3"
    if case == "f_rest count":
        write_custom(path, [("vertex", 10, good[2] + [("float", "f_rest_9", np.zeros(10))])])
        return path, "10 f_rest properties"
    if case == "f_rest numbering":
        props = [("float", "f_rest_10", p[2]) if p[1] == "f_rest_8" else p for p in good[2]]
        write_custom(path, [("vertex", 10, props)])
        return path, "not numbered"
    if case == "truncated":
        write_ply(path, model)
        path.write_bytes(path.read_bytes()[:-5])
        return path, "truncated"
    if case == "truncated ascii":
        write_custom(path, [good], "ascii")
        path.write_bytes(path.read_bytes()[:-300])
        return path, "truncated"
    if case == "bad ascii":
        write_custom(path, [good], "ascii")
        head, body = path.read_bytes().split(b"end_header\n")
        path.write_bytes(head + b"end_header\noops" + body[body.index(b" "):])
        return path, "not a number"
    if case == "non-finite":
        model.opacity_logits[[2, 5]] = [np.nan, np.inf]
        model.log_scales[7, 1] = -np.inf
        write_ply(path, model)
        return path, "3 NaN or Inf values (2 in opacity, 1 in scale_1)"
    if case == "double overflow":
        props = [(t, n, np.full(10, 1e300) if n == "x" else v)
                 for t, n, v in vertex(model, {"x": "double"})[2]]
        write_custom(path, [("vertex", 10, props)])
        return path, "10 NaN or Inf values (10 in x)"  # beyond float32
    if case == "huge log scale":   # finite, but its exp overflows an export's float32 (a .splat held inf)
        model.log_scales[4, 2] = 1e30
        write_ply(path, model)
        return path, "1 Gaussians with a log scale beyond +-40 (Gaussian 4:"
    if case == "huge mean":
        model.means[[1, 6], 0] = [3e15, -1e30]
        write_ply(path, model)
        return path, "2 Gaussians with a mean beyond +-1e+15 (Gaussian 1:"
    if case == "no Gaussians":
        write_custom(path, [("vertex", 0, [(t, n, []) for t, n, _ in good[2]])])
        return path, "no Gaussians"
    if case == "vertex list":
        write_custom(path, [("vertex", 10, good[2] + [("list uchar int", "ids", [[1]] * 10)])])
        return path, "vertex list properties are not 3DGS: ids"
    raise AssertionError(case)


BAD_CASES = ["missing", "directory", "magic", "empty file", "no end_header", "bad count", "bad type",
             "bad format", "no vertex", "missing properties", "f_rest count", "f_rest numbering",
             "truncated", "truncated ascii", "bad ascii", "non-finite", "double overflow", "huge log scale",
             "huge mean", "no Gaussians", "vertex list"]


@pytest.mark.parametrize("case", BAD_CASES)
def test_bad_input_raises_one_clear_line(tmp_path, rng, case):
    path, phrase = bad_file(tmp_path, rng, case)
    with pytest.raises(InputError) as info:
        read_ply(path)
    message = str(info.value)
    assert message.startswith(str(path) + ": ") and "\n" not in message
    assert phrase in message


def test_write_creates_parent_folders(tmp_path, rng):
    model = random_model(rng, 3, 0)
    write_ply(tmp_path / "point_cloud" / "iteration_7" / "point_cloud.ply", model)
    assert_same(model, read_ply(tmp_path / "point_cloud" / "iteration_7" / "point_cloud.ply"))


@pytest.mark.parametrize("existing", [False, True])
def test_failed_write_leaves_nothing_behind(tmp_path, rng, monkeypatch, existing):
    target = tmp_path / "point_cloud.ply"
    if existing:
        target.write_bytes(b"the previous model")
    rows = ply._vertex_rows
    calls = []

    def failing_rows(*args):
        calls.append(args)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return rows(*args)

    monkeypatch.setattr(ply, "_WRITE_ROWS", 4)
    monkeypatch.setattr(ply, "_vertex_rows", failing_rows)
    with pytest.raises(OutputError, match="point_cloud.ply: cannot write: No space left on device"):
        write_ply(target, random_model(rng, 20, 3))
    assert len(calls) == 3  # it did fail midway
    assert os.listdir(tmp_path) == (["point_cloud.ply"] if existing else [])
    if existing:
        assert target.read_bytes() == b"the previous model"


def test_write_replaces_an_existing_file(tmp_path, rng):
    target = tmp_path / "a.ply"
    target.write_bytes(b"old")
    model = random_model(rng, 9, 2)
    write_ply(target, model)
    assert_same(model, read_ply(target))
    assert os.listdir(tmp_path) == ["a.ply"]
