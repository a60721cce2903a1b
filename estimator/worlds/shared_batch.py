"""The particles' inputs and outputs in one block of shared memory, seen as numpy arrays by the
caller of a :class:`~estimator.worlds.pool.WorldPool` and by every worker process: a run sends only a few
numbers through the pipes."""
from __future__ import annotations

import numpy as np

from .batch import PER_PARTICLE, BatchInput, BatchOutput


class SharedBatch:
    """Inputs and outputs of K particles of M objects in ``buffer``, a ``multiprocessing`` RawArray
    of bytes of :meth:`nbytes` size: ``arrays[name]`` views it (``"out."`` names the outputs)."""

    def __init__(self, buffer, n_particles: int, n_objects: int):
        raw = np.frombuffer(buffer, dtype=np.uint8)
        self.arrays: dict[str, np.ndarray] = {
            name: raw[offset:offset + np.prod(shape, dtype=int) * np.dtype(dtype).itemsize].view(dtype).reshape(shape)
            for name, dtype, shape, offset in self._layout(n_particles, n_objects)[0]}

    @staticmethod
    def _fields(K: int, M: int) -> list[tuple[str, type, tuple[int, ...]]]:
        f8, i1, b = np.float64, np.int8, np.bool_
        return [("poses", f8, (K, M, 7)), ("velocities", f8, (K, M, 6)), ("params", f8, (K, M, 5)),
                ("modes", i1, (K, M)), ("check", b, (K, M)), ("target", f8, (K, M, 7)),
                ("target_vel", f8, (K, M, 6)), ("contents", b, (K, M, M)), ("depenetrate", b, (K, M)),
                ("reset", b, (K, M)), ("settled", b, (K, M)), ("vis_query", b, (M,)),
                ("out.poses", f8, (K, M, 7)), ("out.velocities", f8, (K, M, 6)), ("out.modes", i1, (K, M)),
                ("out.max_divergence", f8, (K, M)), ("out.aabbs", f8, (K, M, 2, 3)), ("out.finite", b, (K,)),
                ("out.visible", f8, (K, M))]

    @classmethod
    def _layout(cls, n_particles: int, n_objects: int) -> tuple[list[tuple], int]:
        """``[(name, dtype, shape, byte offset)]`` (offsets 8-byte aligned) and the total size."""
        out, offset = [], 0
        for name, dtype, shape in cls._fields(n_particles, n_objects):
            out.append((name, dtype, shape, offset))
            offset += -(-int(np.prod(shape)) * np.dtype(dtype).itemsize // 8) * 8
        return out, offset

    @classmethod
    def nbytes(cls, n_particles: int, n_objects: int) -> int:
        return cls._layout(n_particles, n_objects)[1]

    def write_inputs(self, batch: BatchInput, rows: np.ndarray) -> None:
        """The inputs of the slots ``rows`` (one per row of ``batch``)."""
        for name in PER_PARTICLE:
            value = getattr(batch, name)
            self.arrays[name][rows] = (name == "reset") if value is None else value  # None: all / none
        self.arrays["vis_query"][...] = batch.vis_query if batch.vis_query is not None else False

    def inputs(self, lo: int, hi: int) -> BatchInput:
        a = self.arrays
        return BatchInput(*(a[name][lo:hi] for name in PER_PARTICLE), a["vis_query"])

    def write_outputs(self, rows: np.ndarray, out: BatchOutput) -> None:
        """The outputs of the slots ``rows`` (one per row of ``out``)."""
        for name in _OUTPUTS:
            self.arrays["out." + name][rows] = getattr(out, name)

    def outputs(self, rows: np.ndarray) -> BatchOutput:
        """A copy of the outputs of the slots ``rows``, in that order."""
        return BatchOutput(*(self.arrays["out." + name][rows] for name in _OUTPUTS))


_OUTPUTS = ("poses", "velocities", "modes", "max_divergence", "aabbs", "finite", "visible")
