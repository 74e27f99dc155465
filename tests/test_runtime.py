import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import runtime
from ipc_taichi.gpus import cuda_present


def test_init_is_idempotent(cpu):
    again = ipc_taichi.init("cpu", "f64")
    assert again is cpu and again.arch == "cpu" and again.dtype == np.float64
    # auto keeps whatever runs already
    assert ipc_taichi.init("auto") is cpu


def test_unknown_arch_and_precision():
    with pytest.raises(ValueError, match="unknown arch"):
        ipc_taichi.init("tpu")
    with pytest.raises(ValueError, match="unknown precision"):
        ipc_taichi.init("cpu", "f16")


def test_environment_selects_arch(monkeypatch, cpu):
    monkeypatch.setenv(runtime.ARCH_ENV, "cpu")
    assert ipc_taichi.init().arch == "cpu"


def test_explicit_cuda(cpu):
    if cuda_present():
        assert ipc_taichi.init("cuda").arch == "cuda"
    else:
        with pytest.raises(ipc_taichi.ArchUnavailableError, match="CUDA was requested"):
            ipc_taichi.init("cuda")
    assert ipc_taichi.init("cpu", "f64").arch == "cpu"


def test_f32_precision_then_back(worked_truth):
    m32 = ipc_taichi.couple(worked_truth, arch="cpu", precision="f32")
    assert m32.dtype == np.float32
    assert runtime.current().precision == "f32"
    m64 = ipc_taichi.couple(worked_truth, arch="cpu", precision="f64")
    assert m64.dtype == np.float64
    np.testing.assert_allclose(m32, m64, rtol=1e-6, atol=1e-3)


def test_a_stale_cache_lock_is_removed_a_young_one_kept(tmp_path):
    """Taichi's cache lock left by a killed process would turn the cache off for good."""
    lock = tmp_path / runtime.CACHE_LOCK
    assert not runtime.clear_stale_cache_lock(tmp_path)  # none: nothing to do
    lock.touch()
    now = lock.stat().st_mtime
    assert not runtime.clear_stale_cache_lock(tmp_path, now=now + runtime.STALE_LOCK_S)
    assert lock.exists()
    assert runtime.clear_stale_cache_lock(tmp_path, now=now + runtime.STALE_LOCK_S + 1)
    assert not lock.exists()


def test_init_clears_a_stale_lock_in_taichis_cache(tmp_path):
    """In a fresh process: ``init`` looks where Taichi's cache is (here moved by
    ``$TI_OFFLINE_CACHE_FILE_PATH``) and removes the stale lock before Taichi starts."""
    import os
    import subprocess
    import sys

    lock = tmp_path / runtime.CACHE_LOCK
    lock.touch()
    old = lock.stat().st_mtime - runtime.STALE_LOCK_S - 10
    os.utime(lock, (old, old))
    env = dict(os.environ, **{runtime.CACHE_PATH_ENV: str(tmp_path), runtime.ARCH_ENV: "cpu"})
    r = subprocess.run([sys.executable, "-c", "import ipc_taichi; ipc_taichi.init()"],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert not lock.exists()


def test_light_source_positions_only_for_this_packages_kernels(cpu):
    """The parse of a kernel in this package says file, line, function and the
    source line; any other kernel keeps Taichi's message with its carets."""
    import ast
    import types

    from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext

    runtime.light_source_positions()  # idempotent: init did it already
    patched = ASTTransformerContext.get_pos_info
    assert patched.taichi_get_pos_info is not patched  # Taichi's own kept, once
    runtime.light_source_positions()
    assert ASTTransformerContext.get_pos_info is patched
    src = ["def step(x):", "    return x + 1.0"]
    node = ast.parse("\n".join(src)).body[0].body[0]
    ours = runtime.__file__.replace("runtime.py", "_kernels.py")
    beside = runtime.__file__.replace("runtime.py", "").rstrip("/\\") + "_plugin/kernels.py"
    for path, carets in ((ours, False), ("/elsewhere/user_kernels.py", True), (beside, True)):
        ctx = types.SimpleNamespace(file=path, lineno_offset=10, src=src, indent=0,
                                    func=types.SimpleNamespace(func=types.SimpleNamespace(
                                        __name__="step")))
        info = patched(ctx, node)
        assert info.startswith(f'File "{path}", line 12, in step:\n    return x + 1.0\n')
        assert ("^" in info) == carets
