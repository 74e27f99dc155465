"""The kernel layouts as objects (issue 37 item 2): one object per layout makes
every choice that depends on it, and no other module of the library compares a
layout's name. Plain Python: nothing here compiles a kernel (the kernels'
outputs are held by tests/test_kernel_identity.py and test_lanes_layout.py)."""

import re
from pathlib import Path

import pytest

from ipc_taichi.engine import LAYOUTS, KernelConfig, StepPlan, kernel_layout
from ipc_taichi.errors import IPCInputError

ROOT = Path(__file__).resolve().parents[1]
# a comparison that tells layouts apart by name: `layout == "lanes"`,
# `"sweep" != x`, `config.layout in STRIP_LAYOUTS`
NAME_TEST = re.compile(r"""(==|!=)\s*["'](lanes|sweep|pixel)["']"""
                       r"""|["'](lanes|sweep|pixel)["']\s*(==|!=)"""
                       r"""|layout\w*\s*(==|!=)|layout\w*\s+(not\s+)?in\s+[A-Z_(]""")
# nearest neighbours, diagonals and the second neighbours along both axes
OFFSETS = ((0, 1), (1, -1), (1, 0), (1, 1), (0, 2), (2, 0))


def test_no_module_but_the_layouts_compares_a_layout_name():
    offenders = []
    for path in sorted((ROOT / "ipc_taichi").rglob("*.py")):
        if path.name == "_layouts.py":
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if NAME_TEST.search(line.split("#")[0]):
                offenders.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert offenders == []
    # the pattern sees the comparisons the engine made before the layout objects
    for before in ('lanes = config.layout == "lanes"', "if config.layout in STRIP_LAYOUTS:",
                   'fast_exp=config.layout == "sweep",', 'n if layout != "pixel" else 0'):
        assert NAME_TEST.search(before), before


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_the_carry_is_worked_out_once_per_layout(precision):
    """Each offset's first carried register and the carry's size, from the
    layout's rule: the sweep carries ``dx`` alphas per pair along the row, the
    pixel layout ``dy`` per pair down the column, ``lanes`` one vector of ``L``
    per pair along the row; the ring and fresh pairs carry nothing."""
    lanes = {"f64": 8, "f32": 16}[precision]
    expect = {"sweep": ((0, 1, 1, 1, 1, 3), 3, ("row", "ring", "ring", "ring", "row", "ring")),
              "pixel": ((0, 0, 0, 1, 1, 1), 3,
                        ("fresh", "fresh", "column", "fresh", "fresh", "column")),
              "lanes": ((0, lanes, lanes, lanes, lanes, 2 * lanes), 2 * lanes,
                        ("row", "ring", "ring", "ring", "row", "ring"))}
    for name, (carry_at, size, sources) in expect.items():
        plan = StepPlan.of(KernelConfig(OFFSETS, "parametric", "zero", False, precision, name))
        assert plan.layout is kernel_layout(name) is LAYOUTS[name]
        assert (plan.carry_at, plan.carry_size, plan.sources) == (carry_at, size, sources)
        assert plan.rings == (name != "pixel") and plan.carries_row == (name != "pixel")
        constant = StepPlan.of(KernelConfig(OFFSETS, "constant", "zero", False, precision, name))
        assert constant.sources == ("fresh",) * 6 and not constant.rings


def test_only_the_sweep_takes_the_inlined_exponential():
    assert [name for name, layout in LAYOUTS.items() if layout.fast_exp] == ["sweep"]


def test_each_layout_shapes_its_workspace():
    """A 100 x 37 frame with reach 2: the padded rows (``lanes``: whole
    vectors), the rows per task, the partials and the ring of each layout."""
    config = KernelConfig(OFFSETS, "parametric", "zero", False, "f64", "sweep")
    sweep, pixel, lanes = (kernel_layout(n) for n in ("sweep", "pixel", "lanes"))
    assert sweep.padded_shape((100, 37), 2, "f64") == (104, 41)
    assert pixel.padded_shape((100, 37), 2, "f64") == (104, 41)
    assert lanes.padded_shape((100, 37), 2, "f64") == (104, 48)
    assert lanes.padded_shape((100, 37), 2, "f32") == (104, 48)
    assert lanes.padded_shape((100, 45), 2, "f32") == (104, 64)
    assert sweep.rows_per_task(100, 37) == lanes.rows_per_task(100, 37) == 32
    assert sweep.rows_per_task(20, 37) == 20
    assert pixel.rows_per_task(100, 37) == 8  # MIN_RUN_ROWS: a small frame
    assert sweep.partials(100, 37, 32) == 4 and pixel.partials(100, 37, 8) == 13 * 37
    assert sweep.maxima_rows(4) == 4 and pixel.maxima_rows(13 * 37) == 1
    assert sweep.ring_shape(config, 100, 41) == (4, 4, 3, 41)
    assert pixel.ring_shape(config, 100, 41) == (1, 1, 1, 1)
    aligned = lanes.host_zeros((3, 48), "f8", 1.0)
    assert aligned.ctypes.data % 64 == 0 and aligned.sum() == 3 * 48
    # a bond map as each host kernel reads it: flat, or as vectors in whole rows
    import numpy as np

    padded = np.arange(2 * 5 * 7, dtype=np.float64).reshape(2, 5, 7)  # a 3 x 3 frame, reach 2
    assert np.array_equal(sweep.bond_array(padded, 2, "f64"), padded.reshape(-1))
    wide = lanes.bond_array(padded, 2, "f64")
    assert wide.shape == (2 * 5, 8) and np.array_equal(wide.reshape(2, 5, 8)[:, :, :7], padded)
    assert not wide.reshape(2, 5, 8)[:, :, 7:].any()


def test_unknown_and_misplaced_layouts_are_refused():
    with pytest.raises(ValueError, match="unknown kernel layout 'diagonal'"):
        kernel_layout("diagonal")
    with pytest.raises(IPCInputError, match="layout 'lanes' runs on the CPU's own arrays"):
        kernel_layout("lanes").check(device_buffers=True)
    kernel_layout("sweep").check(device_buffers=True)
    kernel_layout("lanes").check(device_buffers=False)
