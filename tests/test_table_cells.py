"""The table law in the CPU's ``lanes`` step, which in f32 reads the table as
cells (one record of a cell's four corners per lane, ``ipc_taichi/_lanes.py``
``cell_table``) and in f64 flat: bit for bit the scalar ``sweep``'s
flat-table lookup, on a table whose every cell differs, with signals beyond
both ends of its range (the clamped first and last cells) and a frame whose
rows end inside a vector; two tables in turn each read from its own cells."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import TabulatedLaw


def _random_table(n, seed):
    """A symmetric ``n x n`` table of alphas in [0.004, 0.02]: no two cells alike."""
    r = np.random.default_rng(seed).uniform(0.002, 0.01, (n, n))
    return r + r.T


@pytest.mark.parametrize("precision", ["f32", "f64"])
def test_cells_bit_identical_to_the_flat_table(cpu, precision):
    law = TabulatedLaw(1000.0, 7000.0, _random_table(9, 4), name="random9")
    # signals below the grid's start (-5000 e-), inside it and past its end (56000 e-)
    frame = np.random.default_rng(6).uniform(-5000.0, 70000.0, (13, 37))
    frame[0, :5] = [-5000.0, 1000.0, 56000.0, 70000.0, 55999.0]
    try:
        got = {}
        for layout in ("sweep", "lanes"):
            measured = ipc_taichi.couple(frame, law=law, layout=layout, precision=precision)
            signal, info = ipc_taichi.decouple(measured, law=law, layout=layout,
                                               precision=precision, full_output=True)
            got[layout] = (np.asarray(measured), np.asarray(signal), info.iterations,
                           info.max_delta)
        sweep, lanes = got["sweep"], got["lanes"]
        assert lanes[0].dtype == np.dtype(np.float32 if precision == "f32" else np.float64)
        assert np.array_equal(sweep[0], lanes[0]) and np.array_equal(sweep[1], lanes[1])
        assert sweep[2:] == lanes[2:]
        # the coupling did something, and the lookup is not the same alpha everywhere
        assert np.abs(lanes[0] - frame).max() > 100.0
    finally:
        ipc_taichi.init("cpu", "f64")


def test_two_tables_in_turn(cpu):
    """Two table laws alternately in one process (f32: each its own cells):
    each result the same bits as its first run."""
    frame = np.random.default_rng(8).uniform(0.0, 60000.0, (9, 21))
    laws = [TabulatedLaw(0.0, 65535.0 / 8, _random_table(9, seed)) for seed in (1, 2)]
    run = dict(layout="lanes", precision="f32")
    try:
        first = [np.asarray(ipc_taichi.couple(frame, law=law, **run)) for law in laws]
        assert not np.array_equal(first[0], first[1])
        again = [np.asarray(ipc_taichi.couple(frame, law=law, **run))
                 for law in reversed(laws)][::-1]
        assert all(np.array_equal(a, b) for a, b in zip(first, again))
    finally:
        ipc_taichi.init("cpu", "f64")
