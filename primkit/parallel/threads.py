"""The thread policy: how primkit uses the machine: the cores really available, how many threads to run on them.

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
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time

#: set by primkit when it chose ``OMP_NUM_THREADS`` itself (so that the value is not taken as the user's)
_AUTO_MARK = "PRIMKIT_THREADS_AUTO"


def _cgroup_quota() -> float | None:
    """CPUs allowed by the cgroup CPU quota (v2 ``cpu.max``, v1 ``cpu.cfs_quota_us``), None when unlimited."""
    candidates = [("/sys/fs/cgroup/cpu.max", None),
                  ("/sys/fs/cgroup/cpu/cpu.cfs_quota_us", "/sys/fs/cgroup/cpu/cpu.cfs_period_us"),
                  ("/sys/fs/cgroup/cpu,cpuacct/cpu.cfs_quota_us", "/sys/fs/cgroup/cpu,cpuacct/cpu.cfs_period_us")]
    for quota_path, period_path in candidates:
        try:
            text = open(quota_path).read().split()
            if period_path is None:  # v2: "max 100000" or "150000 100000"
                if text[0] == "max":
                    return None
                return int(text[0]) / int(text[1])
            quota = int(text[0])
            if quota <= 0:
                return None
            return quota / int(open(period_path).read().split()[0])
        except (OSError, ValueError, IndexError, ZeroDivisionError):
            continue
    return None


def _affinity() -> set[int]:
    try:
        return set(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return set(range(os.cpu_count() or 1))


def _physical_cores(cpus: set[int]) -> int | None:
    """Physical cores among ``cpus`` (sysfs topology), None when unknown."""
    cores = set()
    for cpu in cpus:
        base = f"/sys/devices/system/cpu/cpu{cpu}/topology/"
        try:
            cores.add((open(base + "physical_package_id").read().strip(), open(base + "core_id").read().strip()))
        except OSError:
            return None
    return len(cores) or None


def available_cores() -> int:
    """CPUs this process may use: its affinity set, capped by the cgroup quota (at least 1)."""
    cores = len(_affinity())
    quota = _cgroup_quota()
    if quota is not None:
        cores = min(cores, max(1, math.floor(quota + 0.5)))
    return max(1, cores)


def _cpu_jiffies(cpus: set[int]) -> float | None:
    """Busy time (seconds) of ``cpus`` since boot from ``/proc/stat`` (steal counts as busy), or None."""
    try:
        lines = open("/proc/stat").read().splitlines()
    except OSError:
        return None
    hz = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    busy = 0
    for line in lines:
        if not line.startswith("cpu") or line.startswith("cpu "):
            continue
        name, *fields = line.split()
        try:
            cpu = int(name[3:])
        except ValueError:
            continue
        if cpu not in cpus:
            continue
        v = [int(x) for x in fields[:8]] + [0] * max(0, 8 - len(fields))
        user, nice, system, idle, iowait, irq, softirq, steal = v[:8]
        busy += user + nice + system + irq + softirq + steal
    return busy / hz


def _own_cpu() -> float:
    t = os.times()
    return t.user + t.system


class CpuMonitor:
    """Cores used by *other* processes on this process's CPUs, measured between two readings.

    >>> mon = CpuMonitor(); ...; mon.others()   # cores busy elsewhere since the last reading
    """

    def __init__(self):
        self.cpus = _affinity()
        self._last = self._read()

    def _read(self):
        return time.monotonic(), _cpu_jiffies(self.cpus), _own_cpu()

    def others(self, min_interval: float = 0.05) -> float:
        """Mean number of cores other processes kept busy since the previous call (or creation);
        waits until ``min_interval`` seconds have passed. 0 where ``/proc/stat`` is unavailable."""
        t0, busy0, own0 = self._last
        wait = min_interval - (time.monotonic() - t0)
        if wait > 0:
            time.sleep(wait)
        now = self._read()
        self._last = now
        t1, busy1, own1 = now
        if busy0 is None or busy1 is None or t1 <= t0:
            return 0.0
        return max(0.0, ((busy1 - busy0) - (own1 - own0)) / (t1 - t0))


def explicit_threads(threads: int | None = None) -> int | None:
    """The thread count the user asked for, if any: ``threads``, else ``PRIMKIT_THREADS``, else
    ``OMP_NUM_THREADS`` when the user (not primkit) set it, else a torch thread count set by the
    caller to something other than torch's default (the CPUs available at start)."""
    if threads is not None:
        if int(threads) < 1:
            raise ValueError(f"`threads` must be at least 1, got {threads!r}")
        return int(threads)
    for var in ("PRIMKIT_THREADS", "OMP_NUM_THREADS"):
        value = os.environ.get(var, "").strip()
        if not value or (var == "OMP_NUM_THREADS" and os.environ.get(_AUTO_MARK)):
            continue
        try:
            return max(1, int(value.split(",")[0]))
        except ValueError:
            raise ValueError(f"{var}={value!r}: not a number of threads") from None
    torch = sys.modules.get("torch")
    if torch is not None and not os.environ.get(_AUTO_MARK):
        # torch starts with one thread per CPU or per physical core (depending on the build)
        cpus = _affinity()
        current = torch.get_num_threads()
        if current not in (len(cpus), _physical_cores(cpus), os.cpu_count()):
            return current
    return None


def free_cores(*, monitor: CpuMonitor | None = None, interval: float = 0.1) -> int:
    """Cores not kept busy by other processes (a core more than 60% busy elsewhere is not free),
    at least 1; ``monitor`` as in :func:`choose_threads`."""
    cores = available_cores()
    monitor = monitor or CpuMonitor()
    return int(min(cores, max(1, math.floor(cores - monitor.others(interval) + 0.4))))


def choose_threads(threads: int | None = None, *, monitor: CpuMonitor | None = None, interval: float = 0.1) -> int:
    """Threads to run now: the explicit setting (:func:`explicit_threads`) when there is one, else
    the cores free, ``available_cores() - others`` rounded (a core more than half busy elsewhere is
    not counted), at least 1.

    ``monitor``: a :class:`CpuMonitor` whose last reading starts the interval (a fresh one waits
    ``interval`` seconds).
    """
    explicit = explicit_threads(threads)
    if explicit is not None:
        return explicit
    return free_cores(monitor=monitor, interval=interval)


@contextlib.contextmanager
def torch_threads(count: int):
    """Run a block with torch (and the OpenMP/BLAS pools threadpoolctl finds) on ``count`` threads;
    the caller's counts come back afterwards."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(int(count))
    try:
        with limit_native_threads(count):
            yield
    finally:
        torch.set_num_threads(before)


@contextlib.contextmanager
def limit_native_threads(count: int):
    """OpenMP and BLAS pools of the loaded native libraries (threadpoolctl) on ``count`` threads for a block."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency of scikit-learn
        yield
        return
    with threadpool_limits(limits=int(count)):
        yield


class ThreadGovernor:
    """Keeps torch's thread count on the cores free while long work runs.

    ``update()`` is cheap and meant to be called every iteration: every ``interval`` seconds it
    measures what other processes used since the last check (:class:`CpuMonitor`) and sets torch's
    thread count to :func:`choose_threads`' answer. With an explicit setting it sets that once and
    never changes it. ``close()`` gives back the thread count found at creation.

    Attributes
    ----------
    threads : int
        The count in force.
    changes : list of (seconds since start, threads)
    """

    def __init__(self, threads: int | None = None, *, interval: float = 5.0, enabled: bool = True):
        import torch

        self._torch = torch
        self.interval = float(interval)
        self.explicit = explicit_threads(threads)
        self.enabled = enabled
        self._before = torch.get_num_threads()
        self._start = time.monotonic()
        self._next = self._start + self.interval
        self.monitor = CpuMonitor()
        self.threads = self.explicit if self.explicit is not None else choose_threads(monitor=self.monitor, interval=0.1)
        if not enabled:
            self.threads = self._before
        self.changes = [(0.0, self.threads)]
        torch.set_num_threads(self.threads)

    def update(self) -> int:
        """Re-choose when ``interval`` seconds have passed; returns the count in force."""
        if self.explicit is not None or not self.enabled:
            return self.threads
        now = time.monotonic()
        if now < self._next:
            return self.threads
        self._next = now + self.interval
        # our own spinning threads take CPU from the others, so the others' share reads low while
        # we run more threads than cores free: a core counts as free only when under 60% busy
        want = free_cores(monitor=self.monitor, interval=0.0)
        if want != self.threads:
            self.threads = want
            self._torch.set_num_threads(want)
            self.changes.append((round(now - self._start, 1), want))
        return self.threads

    def close(self) -> None:
        self._torch.set_num_threads(self._before)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
