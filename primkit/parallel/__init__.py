"""How primkit uses the machine.

:mod:`~primkit.parallel.threads` holds the thread policy (the cores really free, how many torch and
native threads to run on them, re-chosen during long work; its docstring says why),
:mod:`~primkit.parallel.pool` the local process pool (:func:`parallel_map`) and
:mod:`~primkit.parallel.distribute` shards and cluster executors. It imports nothing else of
primkit, and torch only when torch is already imported (``primkit --help`` stays light).
"""

from .distribute import ExecutorError, Selection, executor_from, parse_shard, shard_indices
from .pool import Terminated, die_with_parent, parallel_map, sigterm_as_interrupt, terminate_pool
from .threads import (CpuMonitor, ThreadGovernor, available_cores, choose_threads, explicit_threads, free_cores,
                      limit_native_threads, torch_threads)

__all__ = [
    "available_cores",
    "CpuMonitor",
    "explicit_threads",
    "free_cores",
    "choose_threads",
    "ThreadGovernor",
    "torch_threads",
    "limit_native_threads",
    "parse_shard",
    "shard_indices",
    "ExecutorError",
    "executor_from",
    "die_with_parent",
    "sigterm_as_interrupt",
    "terminate_pool",
    "Selection",
    "Terminated",
    "parallel_map",
]
