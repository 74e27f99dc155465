"""``ipc-taichi bench`` (``make bench``): decoupling speed, side by side.

One run times, on the same frames, the plain-NumPy peer
(:func:`ipc_taichi.reference.decouple_numpy`),
the paper-faithful NumPy reference (:func:`ipc_taichi.reference.decouple_reference`),
Taichi on the CPU in f64 and f32 and, when a CUDA GPU is present, Taichi on
CUDA in f64 and f32. Frames: uniform 0..60000 (the paper's random frame) and
a star field, square, 512/2048/4096 pixels by default; law ``donlon2018``,
nearest neighbours, zero edge, the paper's stopping rule (20 iterations or
``max|dS| <= 1e-5 max|S|``).

Every configuration runs in a fresh subprocess, so that its peak memory
(``VmHWM`` of ``/proc/self/status``, reset just before the timed runs) is its
own and Taichi's runtime is initialised once for it. The JIT compile time is
measured on a small frame first and reported separately; the timed runs are
warm. Results go to ``bench/results.json`` and ``bench/RESULTS.md``, both
written atomically.

Where the ``jwst`` package is installed, one more row puts the constant-law
decoupler beside the JWST pipeline's own ``ipc`` step on the same ramp
(:mod:`ipc_taichi.bench.pipeline`). A ramp is decoupled from scratch and
warm-started (:mod:`ipc_taichi.bench.ramp`).

Modules: :mod:`~ipc_taichi.bench.cpu` (the CPU rows and the floor),
:mod:`~ipc_taichi.bench.cuda` (the CUDA rows), :mod:`~ipc_taichi.bench.peers`
(NumPy and CuPy peers), :mod:`~ipc_taichi.bench.pipeline` (beside the JWST
step), :mod:`~ipc_taichi.bench.render` (the report, a pure function of the
results), :mod:`~ipc_taichi.bench.launch` (subprocesses, the whole run),
:mod:`~ipc_taichi.bench.startup` (``--help`` and a small decouple in fresh processes),
:mod:`~ipc_taichi.bench.cliramp` (a Roman-like ramp file through the CLI beside its
read and write), :mod:`~ipc_taichi.bench.calfull` (``calibrate`` on a Roman-size set in a
fresh process, its peak memory; run on its own: ``python -m ipc_taichi.bench.calfull``).
"""

from .cpu import KINDS, SIZES, measure_floor, measure_row
from .cuda import CUDA_SIZE, STACK_FRAMES, measure_cuda
from .launch import cuda_present, in_subprocess, machine, run_benchmark, write_results
from .peers import CupyPeer
from .pipeline import measure_pipeline_ipc
from .ramp import RAMP_GROUPS, RAMP_SIZE, measure_ramp
from .render import floor_model, render_cuda, render_markdown, render_pipeline, render_section
from .startup import measure_startup

__all__ = ["run_benchmark", "write_results", "machine", "in_subprocess", "cuda_present",
           "measure_row", "measure_floor", "measure_cuda", "measure_pipeline_ipc", "CupyPeer",
           "render_markdown", "render_cuda", "render_pipeline", "render_section", "floor_model",
           "SIZES", "KINDS", "CUDA_SIZE", "STACK_FRAMES", "measure_ramp", "RAMP_SIZE",
           "RAMP_GROUPS", "measure_startup"]
