"""The thread policy: the cores available, what other processes use of them (a real busy process),
the explicit settings that always win, and the governor that follows the cores free."""

import subprocess
import sys
import time

import pytest
import torch

from primkit import parallel


@pytest.fixture
def clean_env(monkeypatch):
    for var in ("PRIMKIT_THREADS", "OMP_NUM_THREADS", "PRIMKIT_THREADS_AUTO"):
        monkeypatch.delenv(var, raising=False)
    before = torch.get_num_threads()
    torch.set_num_threads(len(parallel.threads._affinity()))  # torch's default: no explicit setting
    yield monkeypatch
    torch.set_num_threads(before)


class FakeMonitor:
    def __init__(self, others):
        self.values = list(others)

    def others(self, min_interval=0.0):
        return self.values.pop(0) if len(self.values) > 1 else self.values[0]


def test_available_cores_is_the_affinity_capped_by_the_quota(monkeypatch):
    assert 1 <= parallel.available_cores() <= len(parallel.threads._affinity())
    monkeypatch.setattr(parallel.threads, "_affinity", lambda: {0, 1, 2, 3})
    monkeypatch.setattr(parallel.threads, "_cgroup_quota", lambda: 1.5)
    assert parallel.available_cores() == 2  # 1.5 CPUs of quota: 2 threads, rounded
    monkeypatch.setattr(parallel.threads, "_cgroup_quota", lambda: None)
    assert parallel.available_cores() == 4


def test_explicit_settings_win(clean_env):
    assert parallel.explicit_threads() is None
    assert parallel.explicit_threads(3) == 3
    clean_env.setenv("OMP_NUM_THREADS", "2")
    assert parallel.explicit_threads() == 2
    clean_env.setenv("PRIMKIT_THREADS_AUTO", "1")  # primkit set OMP_NUM_THREADS itself: not the user's
    assert parallel.explicit_threads() is None
    clean_env.setenv("PRIMKIT_THREADS", "5")
    assert parallel.explicit_threads() == 5 and parallel.choose_threads(monitor=FakeMonitor([1.9])) == 5
    clean_env.delenv("PRIMKIT_THREADS")
    clean_env.delenv("PRIMKIT_THREADS_AUTO")
    clean_env.delenv("OMP_NUM_THREADS")
    torch.set_num_threads(7)  # a script's own torch setting
    assert parallel.explicit_threads() == 7
    with pytest.raises(ValueError, match="PRIMKIT_THREADS"):
        clean_env.setenv("PRIMKIT_THREADS", "many")
        parallel.explicit_threads()


def test_threads_follow_the_cores_free(clean_env):
    clean_env.setattr(parallel.threads, "available_cores", lambda: 2)
    assert parallel.choose_threads(monitor=FakeMonitor([0.0])) == 2
    assert parallel.choose_threads(monitor=FakeMonitor([0.3])) == 2  # a core 30% busy elsewhere still counts
    assert parallel.choose_threads(monitor=FakeMonitor([0.9])) == 1
    assert parallel.choose_threads(monitor=FakeMonitor([2.0])) == 1  # never fewer than one


def _busy_seconds(cpus) -> float:
    """Busy CPU seconds of ``cpus`` since boot, read here from /proc/stat (user, nice, system, irq,
    softirq, steal of each ``cpuN`` line): the machine's side of the account the monitor keeps."""
    import os

    busy = 0
    for line in open("/proc/stat").read().splitlines():
        name, *fields = line.split()
        if name.startswith("cpu") and name[3:].isdigit() and int(name[3:]) in cpus:
            user, nice, system, _idle, _iowait, irq, softirq, steal = (int(x) for x in fields[:8])
            busy += user + nice + system + irq + softirq + steal
    return busy / os.sysconf("SC_CLK_TCK")


def _process_seconds(pid) -> float:
    """CPU seconds (user + system) of process ``pid``, from /proc/PID/stat."""
    import os

    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _own_seconds() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_cpu_monitor_sees_a_real_busy_process_and_not_itself():
    """The monitor's count is the machine's busy time minus this process's own, whatever else runs:
    both are read here independently over the monitor's own interval, and the interval lasts until
    the process being watched has had 0.3 CPU seconds (however loaded the machine is), so counting
    or missing it would be off by far more than the 0.1 s that clock ticks allow."""
    mon = parallel.CpuMonitor()
    tolerance = 0.1  # CPU seconds: a few 10 ms ticks at each end of the interval

    # another process spinning: counted
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.2)
        machine0, spun0 = _busy_seconds(mon.cpus), _process_seconds(spinner.pid)
        mon.others(0.0)
        t0 = mon._last[0]
        while _process_seconds(spinner.pid) - spun0 < 0.3 and time.monotonic() - t0 < 30:
            time.sleep(0.05)
        busy = mon.others(0.0)
        t1 = mon._last[0]
        machine1, spun1 = _busy_seconds(mon.cpus), _process_seconds(spinner.pid)
    finally:
        spinner.kill()
        spinner.wait()
    spun = spun1 - spun0
    assert spun >= 0.3 - tolerance
    assert busy * (t1 - t0) >= spun - tolerance  # the spinner's time is in the count
    assert busy * (t1 - t0) <= machine1 - machine0 + tolerance

    # this process spinning: not counted
    machine0, own0 = _busy_seconds(mon.cpus), _own_seconds()
    mon.others(0.0)
    t0 = mon._last[0]
    while _own_seconds() - own0 < 0.3 and time.monotonic() - t0 < 30:
        pass
    mine = mon.others(0.0)
    t1 = mon._last[0]
    machine1, own1 = _busy_seconds(mon.cpus), _own_seconds()
    own = own1 - own0
    assert own >= 0.3
    expected = max(0.0, (machine1 - machine0) - own)  # the rest of the machine
    assert abs(mine * (t1 - t0) - expected) <= tolerance, (mine * (t1 - t0), expected, own)


def test_governor_steps_down_and_up_and_gives_the_count_back(clean_env):
    clean_env.setattr(parallel.threads, "available_cores", lambda: 2)
    torch.set_num_threads(2)
    clean_env.setattr(parallel.threads, "CpuMonitor", lambda: FakeMonitor([0.0, 1.0, 0.1]))
    gov = parallel.ThreadGovernor(interval=0.0)
    assert gov.threads == 2 and torch.get_num_threads() == 2
    assert gov.update() == 1 and torch.get_num_threads() == 1  # another process took a core
    assert gov.update() == 2  # and left
    assert [t for _, t in gov.changes] == [2, 1, 2]
    torch.set_num_threads(1)
    gov.close()
    assert torch.get_num_threads() == 2  # the count found at creation
    fixed = parallel.ThreadGovernor(1, interval=0.0)
    assert fixed.threads == 1 and fixed.update() == 1 and fixed.changes == [(0.0, 1)]
    fixed.close()
