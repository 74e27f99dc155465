"""Clusters: Slurm allocations, file lists, re-runs, and the Taichi pools of Dask workers.

Detector teams run one Slurm job (or job array) per detector, or Dask workers
started by dask-jobqueue or by ``srun``. This module holds what those need
(the recipes: docs/hpc.md):

- :func:`available_cores`: the CPUs this process may use: ``$SLURM_CPUS_PER_TASK``
  inside a Slurm job, else the CPUs of this process's affinity mask, else every
  core. ``ipc-taichi decouple -o`` starts that many workers by default.
- :func:`read_file_list`: ``--files-from LIST``, one path per line (thousands
  of files exceed the shell's argument limit).
- :func:`already_decoupled`: ``--skip-existing``: an output that carries this
  tool's provenance of a decoupling is skipped on a re-run of a killed job.
- :func:`ipc_taichi.workers.cap_worker_threads`: every worker of a scheduler (ours or one the user
  started) gets a capped Taichi thread pool (``$IPC_TAICHI_THREADS``) before
  its first task initialises Taichi: the CPUs the worker may use, shared by the
  workers on the same host that share them (:func:`thread_caps`).
- :func:`slurm_cluster`: a dask-jobqueue ``SLURMCluster`` of single-threaded
  worker processes whose Taichi pools add up to each job's CPUs
  (``pip install ipc_taichi[hpc]``).
"""

import os
import sys

from . import runtime
from .errors import IPCInputError
from .products import written_by_ipc_taichi
from .runtime import THREADS_ENV

__all__ = ["available_cores", "read_file_list", "already_decoupled", "thread_caps", "joining_cap",
           "worker_facts", "slurm_cluster",
           "SLURM_CPUS_ENV"]

SLURM_CPUS_ENV = "SLURM_CPUS_PER_TASK"


def available_cores():
    """CPUs this process may use: ``$SLURM_CPUS_PER_TASK`` (a positive integer),
    else the size of the affinity mask (what ``srun``/``taskset`` bound it to),
    else ``os.cpu_count()``."""
    try:
        cores = runtime.positive_env(SLURM_CPUS_ENV)
    except ValueError as exc:
        raise IPCInputError(f"${exc}") from None
    if cores is not None:
        return cores
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):  # not Linux
        return os.cpu_count() or 1


def read_file_list(path):
    """The paths listed in ``path`` (``-``: standard input), one per line;
    blank lines and lines starting with ``#`` are left out, surrounding
    white space is stripped. Relative paths are relative to the working
    directory (as ``find . -name '*.fits' > LIST`` writes them)."""
    if path == "-":
        lines = sys.stdin.read().splitlines()
    else:
        try:
            with open(path, encoding="utf-8") as f:
                lines = f.read().splitlines()
        except OSError as exc:
            raise IPCInputError(f"--files-from {path}: cannot read the file list "
                                f"({exc.strerror})") from None
        except UnicodeDecodeError:
            raise IPCInputError(f"--files-from {path}: not a text file of paths") from None
    paths = [line.strip() for line in lines]
    paths = [p for p in paths if p and not p.startswith("#")]
    if not paths:
        raise IPCInputError(f"--files-from {path}: lists no files")
    return paths


def already_decoupled(path):
    """Whether ``path`` is an output this tool decoupled: its provenance
    (FITS ``IPCOP``, Roman ``meta.ipc_taichi``) says ``decouple``. Outputs are
    written to a temporary file and renamed, so such a file is complete."""
    return written_by_ipc_taichi(path, operation="decouple")


def worker_facts():
    """``(host, CPUs of this process's affinity, $IPC_TAICHI_THREADS or None,
    $SLURM_CPUS_PER_TASK or None)``: what :func:`thread_caps` needs from each
    worker (run there by ``client.run``)."""
    try:
        cpus = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = list(range(os.cpu_count() or 1))
    return (os.uname().nodename, cpus, os.environ.get(THREADS_ENV) or None,
            os.environ.get(SLURM_CPUS_ENV) or None)


def thread_caps(facts):
    """``address -> Taichi threads`` for workers described by ``facts``
    (``address -> worker_facts()``): the workers of one host bound to the same
    CPUs share them (``cpus // workers``, at least 1; a worker whose
    ``$SLURM_CPUS_PER_TASK`` is smaller than its mask counts that many); a worker
    whose ``$IPC_TAICHI_THREADS`` is set keeps it."""
    groups = {}
    for address, (host, cpus, _, _) in facts.items():
        groups.setdefault((host, tuple(cpus)), []).append(address)
    caps = {}
    for (_, cpus), members in groups.items():
        for address in members:
            _, _, own, slurm = facts[address]
            if own and own.isdigit() and int(own) > 0:
                caps[address] = int(own)
                continue
            cores = len(cpus)
            if slurm and slurm.isdigit() and 0 < int(slurm) < cores:
                cores = int(slurm)
            caps[address] = max(1, cores // len(members))
    return caps


def joining_cap(facts, workers_on_host):
    """The cap of a worker that joins after the others were capped, from its own
    :func:`worker_facts` and the number of workers the scheduler knows on its host
    (itself included): a worker bound to fewer CPUs than its host has (``srun``,
    ``taskset``) keeps its CPUs; one that sees every CPU shares them with the
    host's workers; its own ``$IPC_TAICHI_THREADS`` is kept."""
    _, cpus, own, slurm = facts
    if own and own.isdigit() and int(own) > 0:
        return int(own)
    cores = len(cpus)
    if slurm and slurm.isdigit() and 0 < int(slurm) < cores:
        return int(slurm)
    if cores < (os.cpu_count() or cores):
        return cores
    return max(1, cores // max(1, int(workers_on_host)))


def slurm_cluster(cpus, memory, processes=None, walltime="01:00:00", queue=None,
                  account=None, python=None, **kwargs):
    """A dask-jobqueue ``SLURMCluster`` for ipc-taichi (``pip install
    ipc_taichi[hpc]``): each job asks Slurm for ``cpus`` CPUs and ``memory``
    and runs ``processes`` (default ``cpus``) single-threaded worker processes,
    each with ``$IPC_TAICHI_THREADS = cpus // processes``, so the Taichi pools
    of one job add up to its CPUs. ``kwargs`` go to ``SLURMCluster``
    (``job_extra_directives``, ``local_directory``, ...). Call ``.scale(jobs=N)``
    or ``.adapt(...)`` on it; ``cluster.job_script()`` shows the job."""
    try:
        from dask_jobqueue import SLURMCluster
    except ImportError:
        raise ImportError("slurm_cluster needs dask-jobqueue: "
                          "pip install 'ipc_taichi[hpc]'") from None
    cpus = int(cpus)
    processes = int(processes or cpus)
    if cpus < 1 or not 1 <= processes <= cpus:
        raise IPCInputError(f"slurm_cluster: cpus={cpus}, processes={processes}: "
                            "needs 1 <= processes <= cpus")
    threads = cpus // processes
    prologue = list(kwargs.pop("job_script_prologue", []))
    prologue.append(f"export {THREADS_ENV}={threads}")
    kwargs.setdefault("scheduler_options", {"dashboard_address": None})
    # cores = worker threads per job: one per process (Taichi is not thread-safe);
    # job_cpu = the CPUs asked of Slurm (--cpus-per-task)
    return SLURMCluster(cores=processes, processes=processes, job_cpu=cpus, memory=memory,
                        walltime=walltime, queue=queue, account=account,
                        python=python or sys.executable, job_script_prologue=prologue,
                        **kwargs)
