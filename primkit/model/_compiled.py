"""Which of the model's compiled kernels serve a call: ``kernels(name, *tensors)``.

The losses and the distance-field lookup have compiled forms on the CPU
(:mod:`primkit.model._field_kernels`, :mod:`primkit.model._union_kernels`, Numba) beside their
torch forms, which serve every other case: CUDA tensors, mixed or other dtypes, inputs the kernels
do not differentiate, and a machine where Numba is missing or fails to load.
"""

from __future__ import annotations

import importlib
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch

__all__ = ["kernels", "over_batch"]

_POOL: ThreadPoolExecutor | None = None


def kernels(name: str, *tensors: torch.Tensor, data: tuple = ()):
    """The kernels module ``primkit.model.<name>`` when every tensor is a CPU tensor of one dtype,
    float32 or float64, and none of ``data`` (inputs the kernels treat as constants) requires a
    gradient; None otherwise, or when the module cannot be imported."""
    dtype = tensors[0].dtype
    if dtype not in (torch.float32, torch.float64):
        return None
    if any(x.device.type != "cpu" or x.dtype != dtype for x in tensors) or any(x.requires_grad for x in data):
        return None
    try:
        return importlib.import_module(f"{__package__}.{name}")
    except ImportError:  # pragma: no cover - Numba is a dependency
        return None


def over_batch(kernel, batched: tuple, scalars: tuple, outputs: tuple) -> None:
    """``kernel(*batched, *scalars, *outputs)``, the batch (axis 0 of ``batched`` and ``outputs``) split
    into as many runs as torch has threads, run side by side: the kernels release the GIL and each
    shape's terms are its own, so the outputs are the same bit for bit however the batch is split.
    With one thread, one call. Measured on the training step's losses (batch 32, two threads): the
    consistency and coverage kernels in about half their one-thread time."""
    global _POOL
    b = len(batched[0])
    runs = min(torch.get_num_threads(), b)
    if runs < 2:
        kernel(*batched, *scalars, *outputs)
        return
    if _POOL is None or _POOL._max_workers < runs:  # noqa: SLF001 - a pool sized to the threads asked for
        _POOL = ThreadPoolExecutor(max_workers=max(runs, os.cpu_count() or 1), thread_name_prefix="primkit-kernels")
    bounds = np.linspace(0, b, runs + 1).round().astype(int)
    jobs = [_POOL.submit(kernel, *(a[lo:hi] for a in batched), *scalars, *(o[lo:hi] for o in outputs))
            for lo, hi in zip(bounds[:-1], bounds[1:]) if hi > lo]
    for job in jobs:
        job.result()
