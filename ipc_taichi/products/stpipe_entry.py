"""The ``stpipe.steps`` entry point: lets ``strun ipc_taichi`` and
``strun calwebb_detector1_taichi`` find the classes of
:mod:`ipc_taichi.products.jwst_step` (and ``strun roman_ipc_taichi`` the Roman step of
:mod:`ipc_taichi.products.roman_step`) by alias (registered in
``pyproject.toml``). It names them without importing ``jwst``, so the
``strun`` command stays quick, as ``stpipe`` asks of its plugins."""

__all__ = ["get_steps"]


def get_steps():
    """``(class name, alias, is a pipeline)`` for each Step this package provides."""
    return [
        ("ipc_taichi.products.jwst_step.IPCTaichiStep", "ipc_taichi", False),
        ("ipc_taichi.products.jwst_step.Detector1TaichiPipeline", "calwebb_detector1_taichi",
         True),
        ("ipc_taichi.products.roman_step.RomanIPCTaichiStep", "roman_ipc_taichi", False),
    ]
