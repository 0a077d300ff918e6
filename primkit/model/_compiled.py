"""Which of the model's compiled kernels serve a call: ``kernels(name, *tensors)``.

The losses and the distance-field lookup have compiled forms on the CPU
(:mod:`primkit.model._field_kernels`, :mod:`primkit.model._union_kernels`, Numba) beside their
torch forms, which serve every other case: CUDA tensors, mixed or other dtypes, inputs the kernels
do not differentiate, and a machine where Numba is missing or fails to load.
"""

from __future__ import annotations

import importlib

import torch

__all__ = ["kernels"]


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
