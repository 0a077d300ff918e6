"""A Python process that runs calls for the fault tests, so that a crash of the interpreter
(a compiled kernel reading past an array) or a hang fails one case instead of killing pytest.

``Sandbox().call("primkit.abstract", arg, model="chair")`` pickles the call to a child process
started once (``python -c``, the test's own ``sys.path``) and returns what came back:
``("ok", summary)``, ``("raised", type name, is a ValueError or TypeError, message)``, or
``("died", return code or "timeout", the child's stderr tail)``. A child that died is started again
for the next call.
"""

from __future__ import annotations

import os
import pickle
import select
import struct
import subprocess
import sys
import time

_CHILD = r"""
import importlib, os, pickle, struct, sys, warnings
warnings.simplefilter("ignore")
out = os.fdopen(os.dup(1), "wb")
os.dup2(2, 1)  # prints go to stderr; stdout carries the answers alone
read = sys.stdin.buffer
while True:
    head = read.read(4)
    if len(head) < 4:
        break
    target, args, kwargs = pickle.loads(read.read(struct.unpack("<I", head)[0]))
    module, name = target.rsplit(".", 1)
    try:
        value = getattr(importlib.import_module(module), name)(*args, **kwargs)
        answer = ("ok", type(value).__name__)
    except Exception as exc:
        answer = ("raised", type(exc).__name__, isinstance(exc, (ValueError, TypeError)), str(exc))
    data = pickle.dumps(answer)
    out.write(struct.pack("<I", len(data)) + data)
    out.flush()
"""


class Sandbox:
    def __init__(self, timeout: float = 120.0):
        self.timeout = timeout
        self.proc = None

    def _start(self):
        env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        self.proc = subprocess.Popen([sys.executable, "-c", _CHILD], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, env=env)

    def call(self, target: str, *args, **kwargs):
        if self.proc is None or self.proc.poll() is not None:
            self._start()
        data = pickle.dumps((target, args, kwargs))
        try:
            self.proc.stdin.write(struct.pack("<I", len(data)) + data)
            self.proc.stdin.flush()
        except BrokenPipeError:
            return self._died()
        answer = self._read(4)
        if answer is None:
            return self._died()
        body = self._read(struct.unpack("<I", answer)[0])
        return self._died() if body is None else pickle.loads(body)

    def _read(self, size: int):
        fd, got, deadline = self.proc.stdout.fileno(), b"", time.monotonic() + self.timeout
        while len(got) < size:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                return None
            chunk = os.read(fd, size - len(got))
            if not chunk:
                return None
            got += chunk
        return got

    def _died(self):
        proc, self.proc = self.proc, None
        if proc.poll() is None:
            proc.kill()
            proc.wait()
            return ("died", "timeout", "")
        return ("died", proc.returncode, "")

    def close(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None
