"""Shards of a collection and the executors that run its jobs elsewhere (Dask, Ray):
``--shard K/N``, ``--skip-done``'s selection and ``--executor ADDRESS``."""

from __future__ import annotations

import contextlib
import os


def parse_shard(text) -> tuple[int, int] | None:
    """``(k, n)`` of ``--shard K/N`` (1-based: ``1/4`` .. ``4/4``), or of ``auto``: the rank
    variables of torchrun (``RANK``, ``WORLD_SIZE``), a SLURM job array (``SLURM_ARRAY_TASK_ID``
    from ``SLURM_ARRAY_TASK_MIN``, ``SLURM_ARRAY_TASK_COUNT``) or SLURM tasks (``SLURM_PROCID``,
    ``SLURM_NTASKS``), in that order; None for no shard (``auto`` with none of them set)."""
    if text is None:
        return None
    text = str(text).strip()
    env = os.environ

    def number(name: str, default=None) -> int:  # a variable that is not an integer is named
        value = env.get(name, default)
        try:
            return int(str(value).strip())
        except ValueError:
            raise ValueError(f"--shard auto: the environment variable {name}={value!r} is not an integer") from None

    if text == "auto":
        if "WORLD_SIZE" in env and "RANK" in env:
            k, n = number("RANK") + 1, number("WORLD_SIZE")
        elif "SLURM_ARRAY_TASK_ID" in env and "SLURM_ARRAY_TASK_COUNT" in env:
            k = number("SLURM_ARRAY_TASK_ID") - number("SLURM_ARRAY_TASK_MIN", "0") + 1
            n = number("SLURM_ARRAY_TASK_COUNT")
        elif "SLURM_PROCID" in env and "SLURM_NTASKS" in env:
            k, n = number("SLURM_PROCID") + 1, number("SLURM_NTASKS")
        else:
            return None
    else:
        k_text, sep, n_text = text.partition("/")
        try:
            k, n = int(k_text), int(n_text)
        except ValueError:
            raise ValueError(f"--shard wants K/N (for example 1/4) or auto, got {text!r}") from None
        if not sep:
            raise ValueError(f"--shard wants K/N (for example 1/4) or auto, got {text!r}")
    if not 1 <= k <= n:
        raise ValueError(f"shard {k}/{n}: K must be between 1 and N")
    return k, n


def shard_indices(count: int, shard) -> list:
    """The positions of shard ``(k, n)`` among ``count`` sorted inputs: every n-th from k - 1, so
    that the shards of one collection are disjoint, together hold every input, and are the same
    on every machine for the same inputs. All of them for None. A :class:`Selection` is its own
    list of positions (what is left of a shard to do)."""
    if shard is None:
        return list(range(count))
    if isinstance(shard, Selection):
        return [i for i in shard.positions if 0 <= i < count]
    k, n = shard
    return list(range(k - 1, count, n))


class Selection:
    """Chosen positions among sorted inputs, passed where a shard ``(k, n)`` goes: the inputs are
    still named as the whole list names them (``primkit abstract --skip-done``)."""

    def __init__(self, positions):
        self.positions = sorted(int(i) for i in positions)

    def __repr__(self) -> str:
        return f"Selection({self.positions})"


class ExecutorError(RuntimeError):
    """``--executor ADDRESS`` cannot be used: its engine is not installed, or nothing answers there."""


class _PoolExecutor:
    """A ``multiprocessing.Pool``-like object (``ray.util.multiprocessing.Pool``) seen as the
    ``map`` of a ``concurrent.futures.Executor``: results in order, as they come. (Ray 2.58 has
    no ``concurrent.futures`` executor of its own; its Pool is the documented drop-in.)"""

    def __init__(self, pool):
        self.pool = pool

    def map(self, func, jobs):
        return self.pool.imap(func, jobs)


def _ray_address(address: str):
    """What ``ray.init`` is given for ``--executor ray...``: None for ``ray`` (a cluster already
    joined, ``RAY_ADDRESS``, one started here by ``ray start``, else a new local one), the Ray
    Client address for ``ray://HOST:10001``, ``auto`` or ``HOST:6379`` for ``ray:auto`` /
    ``ray:HOST:6379`` (a running cluster, from one of its nodes)."""
    if address == "ray":
        return None
    if address.startswith("ray://"):
        return address
    rest = address[len("ray:"):]
    if not rest:
        raise ValueError(f"--executor {address}: give ray, ray:auto, ray:HOST:PORT or ray://HOST:PORT")
    return rest


@contextlib.contextmanager
def executor_from(address):
    """A ``concurrent.futures``-style executor for ``--executor ADDRESS``, closed afterwards.

    * ``tcp://HOST:PORT`` (or any address a ``dask.distributed.Client`` takes; ``dask`` alone
      starts a local cluster): the client's ``get_executor()`` (``pip install primkit[dask]``).
    * ``ray``, ``ray:auto``, ``ray:HOST:PORT`` or ``ray://HOST:PORT``:
      ``ray.util.multiprocessing.Pool`` on that cluster (:func:`_ray_address`; ``pip install
      primkit[ray]``). A Ray instance this call started is shut down afterwards; one the caller
      started (``ray.init``) is used as it is and left running.

    An executor passed as it is (anything with ``map``) is yielded unchanged and left open.
    """
    if address is None or hasattr(address, "map"):
        yield address
        return
    address = str(address)
    if address == "ray" or address.startswith("ray:"):
        ray_address = _ray_address(address)
        try:
            import ray
            from ray.util.multiprocessing import Pool
        except ImportError:
            raise ExecutorError(f"--executor {address} needs Ray: pip install 'ray[default]'") from None
        started = not ray.is_initialized()
        try:
            pool = Pool(ray_address=ray_address)
        except (ConnectionError, ValueError) as exc:  # no cluster there, or one without CPUs
            if started and ray.is_initialized():
                ray.shutdown()
            raise ExecutorError(f"--executor {address}: {str(exc).splitlines()[0]}") from None
        try:
            yield _PoolExecutor(pool)
        finally:
            pool.terminate()
            if started:
                ray.shutdown()
        return
    try:
        from distributed import Client
    except ImportError:
        raise ExecutorError(f"--executor {address} needs dask.distributed: pip install distributed") from None
    try:
        client = Client() if address == "dask" else Client(address)
    except (OSError, ValueError, TypeError) as exc:  # nothing answers there (a timeout), or not an address
        raise ExecutorError(f"--executor {address}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    try:
        yield client.get_executor()
    finally:
        client.close()
