"""The Taichi thread pools of Dask workers, also of a scheduler the user started.

Each worker of ``ipc-taichi decouple --scheduler/--scheduler-file`` (and of
:func:`ipc_taichi.cluster.local_client` with an address) gets
``$IPC_TAICHI_THREADS`` before its first task initialises Taichi
(:func:`cap_worker_threads`): the CPUs it may use, shared by the workers of its
host bound to the same CPUs (:func:`ipc_taichi.hpc.thread_caps`). A plugin does
the same for workers that join later. Imported only where a Dask client is made
(it imports ``distributed``).
"""

import os

from distributed.diagnostics.plugin import WorkerPlugin

from . import runtime
from .hpc import joining_cap, thread_caps, worker_facts
from .runtime import THREADS_ENV

__all__ = ["cap_worker_threads", "TaichiThreadCap", "taichi_threads"]


def _set_threads(threads):
    """On a worker: cap the Taichi pool its first task will start (the user's
    own ``$IPC_TAICHI_THREADS`` is kept). Returns the cap in force."""
    os.environ.setdefault(THREADS_ENV, str(int(threads)))
    return int(os.environ[THREADS_ENV])


def taichi_threads():
    """On a worker: the thread cap of its running Taichi runtime
    (``cpu_max_num_threads``), or ``None`` before its first task."""
    if runtime.current() is None:
        return None
    import taichi as ti

    return int(ti.lang.impl.current_cfg().cpu_max_num_threads)


class TaichiThreadCap(WorkerPlugin):
    """Caps the Taichi pool of every worker, also of those that join later
    (an adaptive cluster): ``caps`` for the workers known when it was
    registered, ``default`` for those that join later (``None``:
    :func:`ipc_taichi.hpc.joining_cap`, from the workers then on its host)."""

    name = "ipc-taichi-thread-cap"

    def __init__(self, caps, default=None):
        self.caps = dict(caps)
        self.default = None if default is None else int(default)

    async def setup(self, worker):
        cap = self.caps.get(worker.address, self.default)
        if cap is None:  # joined later: count the workers the scheduler knows on its host
            try:
                known = (await worker.scheduler.identity()).get("workers", {})
                here = sum(1 for w in known.values() if w.get("host") == worker.ip)
            except Exception:  # an older scheduler: as if alone
                here = 1
            cap = joining_cap(worker_facts(), max(1, here))
        _set_threads(cap)


def cap_worker_threads(client):
    """Cap the Taichi thread pool of every worker of ``client`` (and of workers
    that join later) before any of our tasks runs there: :func:`thread_caps`
    from each worker's :func:`worker_facts`. Returns ``address -> cap``."""
    caps = thread_caps(client.run(worker_facts))
    client.register_plugin(TaichiThreadCap(caps))
    return client.run(_threads_env)


def _threads_env():
    return int(os.environ[THREADS_ENV])
