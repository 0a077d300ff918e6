"""Helpers shared by the benchmark scripts: tables, peak memory, fresh processes, machine load."""

from __future__ import annotations

import os
from pathlib import Path


def table(title: str, headers: list[str], rows: list[list], note: str | None = None) -> None:
    """Print a plain fixed-width table (first column left-aligned, the others right-aligned)."""
    cells = [[str(c) for c in row] for row in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(headers)]

    def line(values):
        return "  ".join(v.ljust(w) if i == 0 else v.rjust(w) for i, (v, w) in enumerate(zip(values, widths)))

    print(f"\n## {title}")
    print(line(headers))
    print("  ".join("-" * w for w in widths))
    for r in cells:
        print(line(r))
    if note:
        print(note)


def maxrss_kib(children: bool = False) -> int:
    """Peak resident set size in KiB: of this process, or of its largest waited-for child.

    For this process it is ``VmHWM`` of ``/proc/self/status`` where available: ``ru_maxrss``
    survives ``exec``, so a spawned process would report its parent's peak. Forked children
    (``children=True``, from ``ru_maxrss`` of ``RUSAGE_CHILDREN``) start from the RSS they share
    with their parent at fork time.
    """
    import resource

    if children:
        return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def _isolated_entry(conn, target, args):
    try:
        conn.send(("ok", target(*args)))
    except BaseException as exc:  # report, never hang the parent
        import traceback

        conn.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
    finally:
        conn.close()


def run_isolated(target, *args):
    """Run ``target(*args)`` in a fresh spawned process and return its result (a picklable dict)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_isolated_entry, args=(child, target, args))
    proc.start()
    child.close()
    try:
        status, value = parent.recv()
    except EOFError:
        status, value = "error", f"process died (exit code {proc.join() or proc.exitcode})"
    proc.join()
    if status != "ok":
        raise RuntimeError(value)
    return value


def load_line() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} cores"


def _run_script(script: str, args, pythonpath: str, cwd: str, env: dict | None = None) -> tuple[dict | list | None, str]:
    import json
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True,
                         env=dict(os.environ, **(env or {}), PYTHONPATH=pythonpath), cwd=cwd)
    if run.returncode:
        return None, (run.stderr.strip().splitlines() or ["failed"])[-1]
    return json.loads(run.stdout.strip().splitlines()[-1]), ""


def run_fresh(script: str, *args: str, env: dict | None = None) -> tuple[dict | list | None, str]:
    """Run ``script`` (Python source printing one JSON line last) with this checkout's primkit in a
    fresh process of this interpreter: the twin of :func:`run_at_revision` for today's code, so
    that both sides of a comparison start the same way; ``env`` adds environment variables.
    Returns ``(parsed JSON, "")`` or ``(None, why)``."""
    import tempfile

    root = str(Path(__file__).resolve().parents[1])
    with tempfile.TemporaryDirectory(prefix="primkit-fresh-") as tmp:
        return _run_script(script, args, root, tmp, env)


def run_at_revision(rev: str, script: str, *args: str) -> tuple[dict | list | None, str]:
    """Run ``script`` (Python source printing one JSON line last) with primkit as it was at git
    revision ``rev``: the revision's ``primkit/`` exported by ``git archive`` into a temporary
    folder first on ``PYTHONPATH``, a fresh process of this interpreter, ``args`` as its argv.

    So that "faster than before" is measured in the same run, on the same machine and files.
    Returns ``(parsed JSON, "")``, or ``(None, why)`` when the revision or the run fails.
    """
    import shutil
    import subprocess
    import tempfile

    root = Path(__file__).resolve().parents[1]
    tmp = tempfile.mkdtemp(prefix="primkit-at-rev-")
    try:
        archive = subprocess.run(["git", "-C", str(root), "archive", rev, "primkit"], capture_output=True)
        if archive.returncode:
            return None, archive.stderr.decode().strip()
        subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
        return _run_script(script, args, tmp, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
