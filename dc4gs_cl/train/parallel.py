"""Training in several processes, data-parallel over views: `mpirun -n P dc4gs-cl train ...`. Each process owns one
OpenCL device (processes on one host take its GPUs in turn where none is named) and renders its share of every
iteration's batch of views; the parameters' gradients are summed over the processes (MPI Allreduce through host
memory), so every process takes the same Adam step and the models stay identical; the densification window is
summed the same way before each densification step and each checkpoint, so every process takes the same
decisions with the same generator. Process 0 alone writes the run folder; the others follow it.

Without MPI (no launcher's environment, or a single process) the group is SingleProcess: every operation is the
identity, and mpi4py is never imported.
"""
from __future__ import annotations

import hashlib
import os
import time

import numpy as np

from ..errors import DeviceError, InputError
from ..runtime import DeviceArrays
from ..statistics import MAX_COLUMNS

# what MPI launchers set in each process they start: the world's size (Open MPI, MPICH's Hydra, PMIx, MVAPICH)
SIZE_VARIABLES = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "MV2_COMM_WORLD_SIZE")
MPI_HINT = "pip install 'dc4gs-cl[mpi]' (mpi4py and Open MPI's wheel)"


class SingleProcess:
    """One process: its share is every view, and there is nothing to add."""
    rank, size, local_rank = 0, 1, 0
    reduced_bytes, reduce_seconds = 0, 0.0   # what the gradients' sums cost: bytes each process sent, wall seconds

    @property
    def writes(self) -> bool:
        """Whether this process writes the run folder (process 0)."""
        return self.rank == 0

    def share(self, views: list) -> list:
        """This process's views of a batch: a contiguous run of len(views) / size."""
        per = len(views) // self.size
        return views[self.rank * per:(self.rank + 1) * per]

    def sum_gradients(self, sums: DeviceArrays) -> None:
        """Every process's gradient sums added, on the device."""

    def reduce_window(self, window: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The densification window over every process's views."""
        return window

    def any(self, flag: bool) -> bool:
        """Whether any process says so (a stop signal one of them received)."""
        return flag

    def broadcast(self, value):
        """Process 0's value, on every process."""
        return value

    def check_same(self, arrays: dict[str, np.ndarray], what: str) -> None:
        """Stop with one line where the processes' arrays differ (they must hold the same model)."""

    def check_same_settings(self, settings: dict[str, object], names: dict[str, str]) -> None:
        """Stop every process with one line naming the first setting (by names[setting], a flag) in which a
        process differs from process 0, before any buffer is sized or message sent by them: ranks started with
        other settings corrupted each other's memory, or hung."""


class MPIGroup(SingleProcess):
    def __init__(self, comm, mpi):
        self.comm, self.mpi = comm, mpi
        self.rank, self.size = comm.Get_rank(), comm.Get_size()
        self.local_rank = comm.Split_type(mpi.COMM_TYPE_SHARED).Get_rank()

    def sum_gradients(self, sums: DeviceArrays) -> None:
        start = time.perf_counter()
        host = sums.download()
        flat = np.concatenate([a.ravel() for a in host.values()])   # one message, not one per group
        self.comm.Allreduce(self.mpi.IN_PLACE, flat, op=self.mpi.SUM)
        at = 0
        for name, a in host.items():
            sums.upload_group(name, flat[at:at + a.size].reshape(a.shape))
            at += a.size
        self.reduced_bytes += flat.nbytes
        self.reduce_seconds += time.perf_counter() - start

    def reduce_window(self, window: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = {}
        for name, column in window.items():
            column = np.ascontiguousarray(column)
            op = self.mpi.MAX if name in MAX_COLUMNS else self.mpi.SUM
            self.comm.Allreduce(self.mpi.IN_PLACE, column, op=op)
            out[name] = column
        return out

    def any(self, flag: bool) -> bool:
        return bool(self.comm.allreduce(int(flag), op=self.mpi.MAX))

    def broadcast(self, value):
        return self.comm.bcast(value, root=0)

    def check_same_settings(self, settings: dict[str, object], names: dict[str, str]) -> None:
        everyone = self.comm.allgather(settings)
        for rank, theirs in enumerate(everyone[1:], 1):
            for name, ours in everyone[0].items():
                if theirs.get(name) != ours:
                    raise InputError(None, f"process {rank} was started with {names.get(name, name)} "
                                           f"{theirs.get(name)!r}, process 0 with {ours!r}: every process of a "
                                           "parallel run takes the same settings")

    def check_same(self, arrays: dict[str, np.ndarray], what: str) -> None:
        digest = hashlib.sha256()
        for name in sorted(arrays):
            digest.update(np.ascontiguousarray(arrays[name]).tobytes())
        digests = self.comm.allgather(digest.hexdigest())
        differ = [rank for rank, d in enumerate(digests) if d != digests[0]]
        if differ:
            raise DeviceError(f"{what}: the model of process {differ[0]} differs from process 0's (they must stay "
                              "identical: the same gradients and decisions on every process; their devices computed "
                              "different ones)")


def launched_size() -> int:
    """The process count an MPI launcher started this process among (1 without one)."""
    for name in SIZE_VARIABLES:
        if os.environ.get(name, "").isdigit():
            return int(os.environ[name])
    return 1


def process_group() -> SingleProcess:
    """This process's group: MPI's world where a launcher started several processes, else a single process."""
    if launched_size() <= 1:
        return SingleProcess()
    try:
        from mpi4py import MPI
    except ImportError:
        raise InputError(None, f"started as one of {launched_size()} MPI processes, but mpi4py is not installed: "
                               f"{MPI_HINT}") from None
    return MPIGroup(MPI.COMM_WORLD, MPI)


def device_of_process(group: SingleProcess, spec: str | None) -> str | None:
    """The device a process trains on: the one named (--device or $DC4GS_DEVICE, the same for every process), else,
    where a host has several GPUs, the local process's turn among them; None: the default device."""
    from ..runtime import DEVICE_ENV, is_simulator, list_devices
    import pyopencl as cl
    if group.size == 1 or spec is not None or os.environ.get(DEVICE_ENV):
        return spec
    gpus = [key for key, d in list_devices() if d.type & cl.device_type.GPU and not is_simulator(d)]
    return gpus[group.local_rank % len(gpus)] if len(gpus) > 1 else None
