"""The local process pool: jobs over worker processes that run their native libraries on one
thread, end with their parent, and stop at once on Ctrl-C or SIGTERM (:func:`parallel_map`)."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

from .threads import free_cores


def die_with_parent(parent: int | None = None) -> None:
    """In a worker process: end it when its parent process ends, however the parent ends (SIGKILL
    included), so that no worker is left running as an orphan. Linux: ``prctl(PR_SET_PDEATHSIG,
    SIGTERM)`` (the kernel signals the worker when the thread that forked it exits); elsewhere
    nothing. ``parent``: the parent's process id, to catch a parent already gone before the call."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    # a forked worker inherits the parent's Python handler (sigterm_as_interrupt), which would turn
    # the signal into an exception the worker's loop catches: the default action ends it
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG (linux/prctl.h)
    except (OSError, AttributeError):  # pragma: no cover - no libc prctl
        return
    if parent is not None and os.getppid() != parent:  # the parent died before the call
        os._exit(1)


class Terminated(KeyboardInterrupt):
    """SIGTERM received: raised where Ctrl-C raises KeyboardInterrupt, so that a run stops the same
    way (its pool ended, outputs left whole, the one-line "interrupted" and exit status 130)."""


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Within the block, SIGTERM raises :class:`Terminated` (a KeyboardInterrupt) in the main
    thread instead of ending the process at once; elsewhere (another thread) nothing changes."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _raise(signum, frame):
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def terminate_pool(pool) -> None:
    """End a ``concurrent.futures.ProcessPoolExecutor``'s workers now (SIGTERM, then SIGKILL after a
    second), for when the run stops: ``shutdown`` alone would wait for the shapes in progress. The
    executor has no public way to reach its processes; ``_processes`` has been there since 3.2."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        with contextlib.suppress(Exception):
            proc.terminate()
    deadline = time.monotonic() + 1.0
    for proc in processes:
        with contextlib.suppress(Exception):
            proc.join(max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.kill()
                proc.join(1.0)


def _one_thread_worker(parent: int | None = None) -> None:
    """Worker-process initialiser: native thread pools (OpenMP, BLAS, torch) on one thread, and
    the worker ends with its parent (:func:`primkit.parallel.die_with_parent`)."""
    die_with_parent(parent)
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ["PRIMKIT_THREADS_AUTO"] = "1"
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1)
    except ImportError:  # pragma: no cover
        pass
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def parallel_map(func, jobs, *, workers: int | None = None, progress: bool = False, desc: str = "", unit: str = "shape",
                 executor=None):
    """``func`` over ``jobs`` in worker processes, results in job order (a progress bar with ``progress``).

    ``workers``: processes (by default the cores free, :func:`primkit.parallel.free_cores`: a core
    another process keeps busy is not counted); 1, or a single job, runs in this process. Each
    worker runs its native libraries (OpenMP, BLAS) on one thread, so that the processes do not
    compete for the cores. ``func`` must be a module-level function and should return its errors
    rather than raise. Processes are forked on Linux (fast, and safe here: workers run
    NumPy/Open3D/libigl code only).

    ``executor``: any object with a ``concurrent.futures.Executor``'s ``map`` (a Dask client's
    ``get_executor()``, :func:`primkit.parallel.executor_from`) runs the jobs there instead.

    Why not joblib (installed with scikit-learn): its process backend, loky, spawns fresh
    interpreters instead of forking, so every run pays their start-up and imports (preparing 12
    procedural chairs on 2 workers, alternating in one run: loky 10.7-11.6 s cold against 4.4-6.5 s
    for this fork pool; 2.4 s only when loky's workers are reused across calls), keeps its workers
    alive for minutes after the run, which the SIGTERM and parent-death handling here would have to
    chase, and sets only the thread-count variables where ``_one_thread_worker`` also tells primkit's
    own thread policy. ``executor=`` remains the way to run elsewhere (Dask, Ray).
    """
    from tqdm.auto import tqdm

    jobs = list(jobs)
    workers = workers or (free_cores() if len(jobs) > 1 else 1)
    bar = tqdm(total=len(jobs), desc=desc, unit=unit, disable=not progress, file=sys.stderr)
    try:
        if executor is not None and jobs:
            for res in executor.map(func, jobs):
                yield res
                bar.update()
        elif workers == 1 or len(jobs) <= 1:
            for job in jobs:
                yield func(job)
                bar.update()
        else:
            import multiprocessing as mp

            ctx = mp.get_context("fork") if sys.platform.startswith("linux") else None
            chunk = max(1, min(64, len(jobs) // (workers * 8) or 1))
            # SIGTERM stops the run as Ctrl-C does; on either the workers are ended at once (and a
            # parent killed outright takes them with it: die_with_parent)
            with sigterm_as_interrupt(), \
                    ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx,
                                        initializer=_one_thread_worker, initargs=(os.getpid(),)) as pool:
                try:
                    for res in pool.map(func, jobs, chunksize=chunk):
                        yield res
                        bar.update()
                except BaseException:
                    terminate_pool(pool)
                    raise
    finally:
        bar.close()
