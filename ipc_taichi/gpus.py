"""One Dask worker per GPU.

Taichi has one runtime per process and uses the first GPU the process can see,
so the way to use several GPUs is one single-threaded worker process per GPU,
each started with ``CUDA_VISIBLE_DEVICES`` set to its own GPU. dask-cuda's
``LocalCUDACluster`` does exactly that where it is installed; otherwise
:func:`gpu_cluster` builds the same thing from ``distributed`` alone (a
``SpecCluster`` of nannies, each given its own environment).

On a cluster, start one worker per GPU yourself, e.g. on each node::

    for g in 0 1 2 3; do
        CUDA_VISIBLE_DEVICES=$g IPC_TAICHI_ARCH=cuda \\
            dask worker tcp://SCHEDULER:8786 --nthreads 1 --nworkers 1 &
    done

(or ``dask cuda worker tcp://SCHEDULER:8786`` with dask-cuda), and pass the
scheduler address to ``ipc-taichi decouple --scheduler``.

"Is there CUDA?" is asked of one function, :func:`cuda_present`, everywhere:
the benchmark's CUDA rows, the test suite's ``gpu`` marker and the Makefile
(which runs this file as a script: ``python ipc_taichi/gpus.py`` prints
``yes`` or nothing, so this module imports nothing of the package).
"""

import ctypes
import os

__all__ = ["CUDA_DRIVER", "cuda_present", "visible_gpus", "worker_env", "gpu_cluster"]

CUDA_DRIVER = "libcuda.so.1"
"""The CUDA driver library (it ships with the NVIDIA driver, so no dependency)."""


def _driver_device_count():
    """How many devices the CUDA driver reports to this process (it honours
    ``CUDA_VISIBLE_DEVICES``); 0 without a driver or when it fails to start."""
    try:
        lib = ctypes.CDLL(CUDA_DRIVER)
    except OSError:
        return 0
    count = ctypes.c_int()
    if lib.cuInit(0) != 0 or lib.cuDeviceGetCount(ctypes.byref(count)) != 0:
        return 0
    return count.value


def cuda_present():
    """Whether this process can run on a CUDA GPU: the driver loads, starts,
    and reports at least one device (``CUDA_VISIBLE_DEVICES=""`` hides them
    all). Does not initialise Taichi or PyTorch."""
    return _driver_device_count() > 0


def visible_gpus():
    """The GPUs this process may hand out: the entries of
    ``CUDA_VISIBLE_DEVICES`` when it is set, else ``"0" .. "n-1"`` for the
    ``n`` devices the CUDA driver reports (none without a driver). Does not
    initialise Taichi."""
    env = os.environ.get("CUDA_VISIBLE_DEVICES")
    if env is not None:
        return [g.strip() for g in env.split(",") if g.strip() and not g.strip().startswith("-")]
    return [str(i) for i in range(_driver_device_count())]


def worker_env(gpu):
    """Environment of the worker that owns ``gpu``: it sees that GPU only,
    runs Taichi on CUDA, and keeps the host-side libraries to one thread (the
    worker's work is on the GPU)."""
    return {"CUDA_VISIBLE_DEVICES": str(gpu), "IPC_TAICHI_ARCH": "cuda",
            "OMP_NUM_THREADS": "1"}


def gpu_cluster(gpus=None, use_dask_cuda=None, **scheduler_options):
    """A local Dask cluster with one single-threaded worker per GPU.

    Parameters
    ----------
    gpus : list of str, optional
        GPU ids (as ``CUDA_VISIBLE_DEVICES`` spells them); default
        :func:`visible_gpus`.
    use_dask_cuda : bool, optional
        Use dask-cuda's ``LocalCUDACluster`` (default: when importable).
    **scheduler_options
        Passed to the scheduler (e.g. ``dashboard_address=None``).

    Returns
    -------
    distributed.deploy.Cluster
        Connect with ``distributed.Client(cluster)``; close it when done.

    Raises
    ------
    RuntimeError
        No GPU to hand out.
    """
    gpus = list(visible_gpus() if gpus is None else gpus)
    if not gpus:
        raise RuntimeError("no GPU visible: set CUDA_VISIBLE_DEVICES or install the "
                           "NVIDIA driver")
    if use_dask_cuda is None:
        try:
            import dask_cuda  # noqa: F401
            use_dask_cuda = True
        except ImportError:
            use_dask_cuda = False
    if use_dask_cuda:
        from dask_cuda import LocalCUDACluster

        return LocalCUDACluster(CUDA_VISIBLE_DEVICES=",".join(gpus), threads_per_worker=1,
                                **scheduler_options)
    from distributed import Nanny, Scheduler, SpecCluster

    scheduler_options.setdefault("dashboard", False)
    scheduler_options.setdefault("dashboard_address", ":0")  # no fixed port to collide with
    workers = {f"gpu-{g}": {"cls": Nanny, "options": {"nthreads": 1, "env": worker_env(g)}}
               for g in gpus}
    return SpecCluster(workers=workers,
                       scheduler={"cls": Scheduler, "options": scheduler_options})


if __name__ == "__main__":  # the Makefile's question: `python ipc_taichi/gpus.py`
    print("yes" if cuda_present() else "")
