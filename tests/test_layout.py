"""Host/device records: each written once (layout.Record), so the host and the kernels agree on every field.
The structs passed by value are checked on the device (offsets and size as the compiler lays them out, and
a round trip of a packed value through a kernel); the rows' offsets are checked where they are made."""
import numpy as np
import pyopencl as cl
import pytest

from dc4gs_cl.densify import STRATEGIES, DC4GSConfig
from dc4gs_cl.errors import DeviceError
from dc4gs_cl.layout import Field, Record
from dc4gs_cl.records import STRUCTS, records_header
from dc4gs_cl.runtime import kernel_source
from dc4gs_cl.statistics import SPLIT_LANES, SumsLayout, geometry_record

PROBE = """
__kernel void probe(__global uint *layout, const {type} value, __global uint *lanes) {{
    {type} probe;
    __private char *base = (__private char *)&probe;
    layout[0] = sizeof({type});
{offsets}
    __private const uint *bits = (__private const uint *)&value;
    for (uint i = 0; i < sizeof({type}) / 4; ++i) lanes[i] = bits[i];
}}
"""


@pytest.mark.parametrize("type_name", STRUCTS)
def test_struct_record_matches_the_device_layout(rt, rng, type_name):
    """sizeof and every field's offset as the device compiles the generated struct equal the record's (4 bytes
    a lane, no padding), and a value packed by the host reaches the kernel lane for lane."""
    record = STRUCTS[type_name]
    offsets = "\n".join(f"    layout[{i + 1}] = (uint)((__private char *)&probe.{f.name} - base);"
                        for i, f in enumerate(record.fields))
    source = PROBE.format(type=type_name, offsets=offsets)
    program = cl.Program(rt.context, kernel_source("common.h") + source).build(options=rt.build_options())
    layout = rt.to_device(np.full(len(record.fields) + 1, 0xFFFFFFFF, np.uint32))
    lanes = rt.to_device(np.full(record.width, 0xFFFFFFFF, np.uint32))
    bits = rng.integers(0, 2**31, record.width).astype(np.uint32)     # distinct, arbitrary lane bits
    value = np.frombuffer(bits.tobytes(), record.dtype)[0]
    program.probe(rt.queue, (1,), (1,), layout, value, lanes)
    got = rt.to_host(layout, len(record.fields) + 1, np.uint32)
    assert got[0] == 4 * record.width == record.dtype.itemsize
    assert list(got[1:]) == [4 * record.offsets[f.name] for f in record.fields]
    np.testing.assert_array_equal(rt.to_host(lanes, record.width, np.uint32), bits)


def test_records_header_is_generated_into_the_kernels():
    assert records_header() in kernel_source("project.cl")
    for name, record in STRUCTS.items():
        assert record.c_struct(name) in records_header()


def test_record_offsets_views_and_rows():
    r = Record("T", [("a", 2), Field("b", 1, "int"), ("c", 3)])
    assert r.offsets == {"a": 0, "b": 2, "c": 3} and r.width == 6
    assert r.defines() == {"T_A": 0, "T_B": 2, "T_C": 3, "T_WIDTH": 6}
    rows = np.arange(12, dtype=np.float32).reshape(2, 6)
    v = r.views(rows)
    np.testing.assert_array_equal(v["b"], [2, 8])
    np.testing.assert_array_equal(r.rows(v), rows)
    v["c"][:] = -1                                      # views, not copies
    assert (rows[:, 3:] == -1).all()
    assert r == Record("T", [("a", 2), Field("b", 1, "int"), ("c", 3)]) and hash(r) == hash(Record("T", r.fields))
    with pytest.raises(ValueError):
        Record("T", [("a", 1), ("a", 2)])
    with pytest.raises(ValueError):
        r.pack(d=1)


@pytest.mark.parametrize("strategy", STRATEGIES)
@pytest.mark.parametrize("dc4gs", [DC4GSConfig(), DC4GSConfig(dcc=True), DC4GSConfig(dcs=True),
                                   DC4GSConfig(dcc=True, dcs=True, pooling="window", candidates=7)])
def test_sums_and_window_derive_from_one_spec(strategy, dc4gs):
    """The backward's sums and the window are made from the strategy's one StatisticsSpec: the window has DC4GS'
    columns exactly when the sums carry DC4GS' sums, and the split costs' width is the sums' candidate count.
    Every record kernels/densify_stats.cl sees gets distinct define names, and the split lanes reach the kernels
    with the layout's defines."""
    spec = STRATEGIES[strategy](dc4gs=dc4gs).statistics
    sums, window = spec.sums, spec.window
    assert ("dc" in sums.record) == ("dcc_abs" in window) == dc4gs.enabled
    assert ("split" in sums.record) == ("split_costs" in window) == dc4gs.dcs
    if dc4gs.dcs:
        assert window.widths()["split_costs"] == sums.split_candidates == dc4gs.candidate_count
    split = [geometry_record(sums.split_candidates).defines(), SPLIT_LANES.defines()] if sums.split_candidates else []
    defines = [sums.record.defines(), window.defines()] + split
    names = [k for d in defines for k in d]
    assert len(names) == len(set(names))
    assert not sums.split_candidates or set(SPLIT_LANES.defines()) <= set(sums.defines())
    assert spec.defines()["TRACK_TOTAL"] == window.offsets[STRATEGIES[strategy](dc4gs=dc4gs).split_criterion.total]


def test_sums_layout_refuses_inconsistent_switches():
    for bad in (dict(dc_stats=True), dict(stats=True, split_candidates=5),
                dict(stats=True, dc_stats=True, split_candidates=4)):
        with pytest.raises(ValueError):
            SumsLayout(**bad)


def test_a_switch_the_host_does_not_pass_stops_the_build(rt):
    """The kernels keep no defaults (REQUIRE_DEFINED): a missing switch fails the build with a message naming
    it, instead of reading as 0 and silently choosing a variant."""
    defines = {"PAIR_SUMS": 1, "STATS": 1, "DC_STATS": 0, "PIXELS_PER_ITEM": 256, "BATCH": 32, "FAST_EXP": 1,
               "ALPHA_CUT": 1, **SumsLayout(stats=True).record.defines()}   # no SPLIT_CANDIDATES
    with pytest.raises(DeviceError, match="SPLIT_CANDIDATES") as failed:   # not among the options: the log names it
        rt.program("rasterize_backward.cl", defines)
    assert "-DSPLIT_CANDIDATES" not in str(failed.value)
