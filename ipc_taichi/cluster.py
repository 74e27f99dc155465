"""Many frames and huge mosaics on Dask (dask.array + dask.distributed).

Taichi has one runtime per process and is not thread-safe, so every Dask
worker is a **process with one thread**; each worker initialises Taichi
lazily, the first time one of its tasks calls :func:`ipc_taichi.decouple`,
and keeps it for later tasks. Taichi's own CPU thread pool in each worker is
capped at ``cores // workers`` (at least 1, :func:`worker_threads`, passed as
``$IPC_TAICHI_THREADS``, see :mod:`ipc_taichi.runtime`): uncapped, every
worker ran one thread per core and two workers were no faster than one.

- :func:`local_client` starts such a ``LocalCluster`` (or connects to a
  running scheduler).
- :func:`decouple_files` decouples many product files (FITS or Roman ASDF,
  through :func:`ipc_taichi.products.decouple_file`), one task per file. The
  worker reads the input and writes the output itself (atomically: temporary
  file beside the output, renamed on success), so frames never travel through
  the client. A corrupt file or a dying worker fails that file only; the
  others complete.
- :func:`decouple_stack` decouples the frames of a 3-D cube in parallel, one
  frame per task (``dask.array.map_blocks``).
- :func:`decouple_mosaic` decouples one frame larger than a worker with
  ``dask.array.map_overlap`` and ``depth = iterations * reach``: exact for the
  same reason as :mod:`ipc_taichi.tiling`. The iteration count of the paper's
  stopping rule is decided first, from per-tile maxima computed on the workers.
"""

import dataclasses
import functools
import os

import numpy as np

from . import iteration
from .bondmap import BondMap
from .decoupling import decouple
from .errors import IPCInputError
from .gpus import gpu_cluster
from .model import CouplingModel
from .products import decouple_file
from .products.options import ProductOptions
from .runtime import THREADS_ENV
from .tiling import decouple_blocks, halo_for, tile_maxima

__all__ = ["local_client", "decouple_files", "decouple_stack", "decouple_mosaic",
           "FileResult", "worker_threads"]


def worker_threads(workers, cores=None):
    """Taichi CPU threads per worker so that ``workers`` of them add up to the
    ``cores`` (default: this machine's): ``cores // workers``, at least 1."""
    cores = int(cores or os.cpu_count() or 1)
    return max(1, cores // max(1, int(workers)))


def local_client(scheduler=None, workers=None, memory_limit="auto", gpus=None):
    """A ``distributed.Client``: to ``scheduler`` (an address) if given; else,
    with ``gpus`` (a list of GPU ids, empty for every visible GPU), to a new
    cluster of one single-threaded worker per GPU
    (:func:`ipc_taichi.gpus.gpu_cluster`); else to a new ``LocalCluster`` of
    ``workers`` single-threaded processes, whose Taichi thread pools are capped
    at :func:`worker_threads` each."""
    import logging

    from distributed import Client, LocalCluster

    # Dask logs worker starts, stops and failed tasks; the command line reports
    # each failed file itself, in one line
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    if scheduler:
        return Client(scheduler)
    if gpus is not None:
        client = Client(gpu_cluster(list(gpus) or None))
        client._ipc_taichi_owns_cluster = True
        return client
    import dask

    workers = int(workers or min(4, os.cpu_count() or 1))
    # a task whose worker dies is retried once on another worker, then failed
    # (the default, 3, would let one bad file kill four workers)
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True,
            dashboard_address=None, memory_limit=memory_limit, silence_logs=logging.CRITICAL,
            env={THREADS_ENV: os.environ.get(THREADS_ENV) or str(worker_threads(workers))})
    client = Client(cluster)
    client._ipc_taichi_owns_cluster = True
    return client


def close_client(client):
    """Close ``client`` and, if :func:`local_client` started it, its cluster."""
    cluster = client.cluster if getattr(client, "_ipc_taichi_owns_cluster", False) else None
    client.close()
    if cluster is not None:
        cluster.close()


class FileResult(dict):
    """What happened to one input file: ``input``, ``output``, ``ok``, and
    ``iterations``/``converged`` or ``error`` (a one-line message)."""


def decouple_one_file(input_path, output_path, options):
    """Read, decouple and write one product (runs on a worker). ``options``:
    the keyword arguments of :func:`ipc_taichi.products.decouple_file`."""
    return decouple_file(input_path, output_path, **options)


def _task_options(options, model):
    """``options`` (a ProductOptions, or a dict of its fields plus any of
    ``model``/``law``/``geometry``/``edge``) -> the model arguments and one
    :class:`~ipc_taichi.products.ProductOptions`."""
    if isinstance(options, ProductOptions):
        options = {"options": options}
    options = dict(options or {})
    coupling = {k: options.pop(k) for k in ("model", "law", "geometry", "edge") if k in options}
    if model is not None:
        if coupling.get("model") is not None:
            raise IPCInputError("decouple_files: model given twice")
        coupling["model"] = model
    product = ProductOptions.from_kwargs(options.pop("options", None), **options)
    return coupling, product


def decouple_files(pairs, options, client, progress=None, task=None, model=None):
    """Decouple ``(input, output)`` pairs on ``client``'s workers.

    Parameters
    ----------
    pairs : list of (str, str)
    options : ProductOptions or dict
        The product options (:class:`ipc_taichi.products.ProductOptions`), or
        a dict of their fields, which may also hold ``model`` or
        ``law``/``geometry``/``edge`` (as :func:`ipc_taichi.products.decouple_file`).
        Existing outputs are refused up front unless ``overwrite`` (the check runs
        on the client: inputs and outputs must be on a file system the client and
        the workers share).
    client : distributed.Client
    progress : callable, optional
        Called with each :class:`FileResult` as it completes.
    task : callable, optional
        ``task(input, output, options) -> summary`` run per file (default
        :func:`decouple_one_file`), ``options`` being the keyword arguments of
        :func:`ipc_taichi.products.decouple_file`.
    model : CouplingModel or str, optional
        The coupling model (or a model file), instead of ``options["model"]``.

    Returns
    -------
    list of FileResult, in the order of ``pairs``.
    """
    import uuid

    from distributed import as_completed

    task = task or decouple_one_file
    run_id = uuid.uuid4().hex[:8]  # unique keys: never reuse an earlier run's result
    results = [None] * len(pairs)
    # Refuse existing outputs here, once, before any work. A worker that dies loses
    # the results it holds and Dask runs those tasks again; such a rerun must be
    # allowed to replace the output its first run wrote (same content, atomic).
    coupling, product = _task_options(options, model)
    overwrite = product.overwrite
    options = dict(coupling, options=product.replace(overwrite=True))
    futures = {}
    for k, (src, dst) in enumerate(pairs):
        if not overwrite and os.path.exists(dst):
            results[k] = FileResult(input=src, output=dst, ok=False,
                                    error=f"{dst}: exists (use --overwrite to replace it)")
            if progress is not None:
                progress(results[k])
            continue
        # pure=False: the same file twice is two tasks; retries=0: a task that
        # killed its worker is not run again on the next one
        fut = client.submit(task, src, dst, options, pure=False, retries=0,
                            key=f"decouple-{run_id}-{k}-{os.path.basename(src)}")
        futures[fut] = k
    for fut in as_completed(list(futures)):
        k = futures[fut]
        src, dst = pairs[k]
        res = FileResult(input=src, output=dst)
        try:
            summary = fut.result()
            res.update(ok=True, **summary)
        except Exception as exc:  # the file's own failure, or its worker died
            res.update(ok=False, error=_one_line(src, exc))
        results[k] = res
        if progress is not None:
            progress(res)
    return results


def _one_line(path, exc):
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    name = type(exc).__name__
    if name == "KilledWorker":
        return f"{path}: the worker running it died (out of memory or killed)"
    if text.startswith(str(path)):
        return text
    return f"{path}: {name}: {text}" if text else f"{path}: {name}"


def _decouple_frames(block, options):
    return np.asarray(decouple(block, **options), dtype=np.float64)


def decouple_stack(cube, client, **options):
    """Decouple the frames of a 3-D ``cube`` in parallel, one frame per task.

    ``options`` are those of :func:`ipc_taichi.decouple`. Returns float64.
    """
    import dask.array as da

    cube = np.asarray(cube)
    if cube.ndim != 3:
        raise IPCInputError(f"decouple_stack: expected a 3-D cube, got shape {cube.shape}")
    x = da.from_array(cube, chunks=(1,) + cube.shape[1:])
    y = x.map_blocks(_decouple_frames, options, dtype=np.float64)
    return client.compute(y).result()


def _decouple_fixed(block, *bonds, n, options, offsets=None):
    """``n`` Jacobi iterations on one overlapped block (map_overlap's function);
    ``bonds``: the model's bond map over the same block (one array per offset
    of ``offsets``), the model in ``options`` without its map."""
    if bonds:
        options = dict(options, model=dataclasses.replace(
            options["model"], bonds=BondMap(offsets, np.stack(bonds))))
    return np.asarray(decouple(block, max_iter=n, tol=0, **options), dtype=np.float64)


def _tile_job(core, frame, model, shape, halo, n, arch, precision):
    return tile_maxima(lambda window: frame[window], shape, core, halo, n, model, arch,
                       precision)


def decouple_mosaic(measured, client, chunk=1024, law=None, geometry=None,
                    edge=None, max_iter=iteration.MAX_ITER, tol=iteration.TOL, arch=None,
                    precision=None, full_output=False, *, model=None):
    """Decouple one large frame across the workers; equal to :func:`ipc_taichi.decouple`.

    1. The iteration count: the paper's rule on the whole frame, from per-tile
       maxima of ``|S_q - S_(q-1)|`` and ``|S_q|`` computed on the workers
       (tiles of ``chunk``, halo ``n * reach``; see :mod:`ipc_taichi.tiling`).
    2. ``dask.array.map_overlap`` over chunks of ``chunk`` with
       ``depth = count * reach`` and no boundary padding (the frame's own edge
       rule applies at its edge), exactly ``count`` iterations per block.
    """
    import dask.array as da

    frame = np.asarray(measured, dtype=np.float64)
    if frame.ndim != 2:
        raise IPCInputError(f"decouple_mosaic: expected a 2-D frame, got shape {frame.shape}")
    # law= with model= is refused, as ipc_taichi.decouple refuses it
    model = CouplingModel.resolve(law, geometry, edge, model=model)
    shared = client.scatter(frame, broadcast=False)
    shared_model = client.scatter(model, broadcast=False)  # its bond map, if any, sent once

    def mapper(n, halo, cores):
        job = functools.partial(_tile_job, shape=frame.shape, halo=halo, n=n,
                                arch=arch, precision=precision)
        futures = client.map(job, cores, [shared] * len(cores), [shared_model] * len(cores),
                             pure=False)
        for fut in futures:
            yield fut.result()

    info = decouple_blocks(None, None, frame.shape, chunk, model, max_iter, tol, arch, precision,
                           progress=False, mapper=mapper)
    n = info.iterations
    depth = halo_for(n, model.geometry)
    x = da.from_array(frame, chunks=chunk)
    # a bond map goes with the frame, block by block, with the same overlap
    options = dict(model=dataclasses.replace(model, bonds=None), arch=arch, precision=precision)
    bonds = [] if model.bonds is None else [da.from_array(b, chunks=chunk)
                                            for b in model.bonds.values]
    y = da.map_overlap(_decouple_fixed, x, *bonds, depth=depth, boundary="none", trim=True,
                       dtype=np.float64, n=n, options=options,
                       offsets=None if model.bonds is None else model.bonds.offsets)
    out = client.compute(y).result()
    return (out, info) if full_output else out

