"""How primkit uses the machine: the cores really available, how many threads to run on them.

A small machine is often shared (another training run, a test suite, a browser), and torch's
OpenMP threads do not cope: with 2 threads on 2 cores and one of them busy elsewhere, a training
step of the losses measured 24x slower than with 1 thread, because every parallel region waits for
the thread whose core is taken. So primkit chooses its thread count from the cores *free*:

* :func:`available_cores`: the CPUs this process may run on (``os.sched_getaffinity``), capped by
  the cgroup CPU quota when one is set (containers, SLURM).
* :class:`CpuMonitor`: how much of those CPUs other processes used over an interval, from
  ``/proc/stat`` minus this process's own CPU time (Linux; elsewhere nobody is counted).
* :func:`choose_threads`: the thread count for now. **An explicit setting always wins**: the
  ``threads`` argument, ``PRIMKIT_THREADS``, ``OMP_NUM_THREADS`` (set by the user, not by
  primkit), or a torch thread count the caller set to something else than torch's default.
* :class:`ThreadGovernor`: re-chooses every few seconds during long work (training), so that a
  run started on a quiet machine steps down when another process takes a core, and back up when
  it leaves; :func:`torch_threads` holds a count for a block and gives the caller's back.

Nothing here imports torch unless torch is already imported (``primkit --help`` stays light).

The package: :mod:`~primkit.parallel.threads` (the thread policy above),
:mod:`~primkit.parallel.pool` (the local process pool, :func:`parallel_map`) and
:mod:`~primkit.parallel.distribute` (shards and cluster executors).
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
