"""The records every reader hands the correction: the array's plan and the run's settings.

:func:`~ipc_taichi.products.correct_frames` takes an array's plan (an
:class:`~ipc_taichi.products.plan.ArrayPlan`, or a
:class:`~ipc_taichi.products.FramePlan` for bare arrays) and one
:class:`~ipc_taichi.products.RunSettings` built from the options; the run's
record (:class:`~ipc_taichi.products.provenance.Provenance`) is built from the
same records.
"""

import dataclasses

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.errors import IPCInputError
from ipc_taichi.model import CouplingModel
from ipc_taichi.products import FramePlan, ProductOptions, RunSettings, correct_frames
from ipc_taichi.products.correction import FrameBuffers
from ipc_taichi.products.provenance import Provenance
from ipc_taichi.reference import couple_reference
from tests.helpers import one_array_plan

MODEL = CouplingModel.resolve("donlon2018")


def test_settings_take_every_run_field_of_the_options():
    """Each settings field (but the operation) is the option of its name: a
    field added to one and forgotten by :meth:`RunSettings.of` fails here."""
    changed = dict(max_iter=7, tol=1e-3, arch="cpu", precision="f32", unphysical="keep",
                   progress=print, tile=8)
    names = {f.name for f in dataclasses.fields(RunSettings)} - {"operation"}
    assert names == set(changed)
    assert names <= {f.name for f in dataclasses.fields(ProductOptions)}
    base = RunSettings.of(ProductOptions(), "couple")
    assert base.operation == "couple"
    for name, value in changed.items():
        settings = RunSettings.of(ProductOptions().replace(**{name: value}))
        assert getattr(settings, name) == value != getattr(base, name), name


@pytest.mark.parametrize("bad, said", [(dict(operation="fold"), "operation"),
                                       (dict(max_iter=0), "max_iter"),
                                       (dict(tol=float("nan")), "tol")])
def test_settings_refuse_what_means_nothing(bad, said):
    with pytest.raises(IPCInputError, match=said):
        RunSettings(**bad)


def test_an_array_plan_is_a_frame_plan():
    """Every field :func:`correct_frames` reads of a :class:`FramePlan` is
    there, with the same meaning, on the plan every reader passes."""
    array = one_array_plan(MODEL, (6, 8), "in.fits[SCI]").arrays[0]
    for field in dataclasses.fields(FramePlan):
        assert hasattr(array, field.name), field.name
    assert array.region == (slice(0, 6), slice(0, 8)) and array.label == "in.fits[SCI]"


def test_bare_arrays_are_decoupled_in_electrons(cpu):
    """A stack in DN through a :class:`FramePlan` (gain 2 e-/DN) is, frame by
    frame, the decoupler on its charge, back in DN; the previous frame's
    buffers, written again, change no bit of the next."""
    rng = np.random.default_rng(5)
    charge = np.stack([couple_reference(rng.uniform(1000, 50000, (12, 10))) for _ in range(3)])
    settings = RunSettings("decouple", tol=1e-9)
    out, infos = correct_frames(charge / 2.0, FramePlan(MODEL, scale=2.0), settings)
    assert len(infos) == 3 and all(i.converged for i in infos)
    for k in range(3):
        alone = ipc_taichi.decouple(charge[k], model=MODEL, tol=1e-9)
        np.testing.assert_array_equal(out[k], alone / 2.0)


def test_frame_buffers_are_taken_once_and_only_of_their_shape():
    buffers = FrameBuffers()
    assert buffers.take_charge((2, 3)) is None
    held = np.zeros((2, 3))
    buffers.charge = held
    assert buffers.take_charge((3, 2)) is None  # another shape: dropped, not kept
    assert buffers.take_charge((2, 3)) is None
    buffers.charge, buffers.answer = held, held
    assert buffers.take_charge((2, 3)) is held and buffers.take_charge((2, 3)) is None
    assert buffers.take_answer((2, 3)) is held and buffers.take_answer((2, 3)) is None


class _Info:
    def __init__(self, iterations, converged):
        self.iterations, self.converged, self.max_delta = iterations, converged, [0.0]


def test_the_record_and_the_summary_come_from_the_plan_and_the_settings():
    plan = one_array_plan(MODEL, (4, 4), "in.fits[SCI]", "asked for", "given: 9 e-")
    prov = Provenance(plan, RunSettings("decouple", 30, 1e-4, tile=16))
    assert (prov.operation, prov.max_iter, prov.tol, prov.tile) == ("decouple", 30, 1e-4, 16)
    assert (prov.edge_reason, prov.pedestal_text, prov.arch) == ("asked for", "given: 9 e-", "")
    prov.infos[1] = [_Info(5, True)]
    prov.unphysical[1] = 2
    summary = prov.summary("out.fits")
    assert summary["hdus"] == ["in.fits[SCI]"] and summary["label"] == "in.fits[SCI]"
    assert (summary["iterations"], summary["converged"], summary["masked_unphysical"]) == (
        5, True, 2)
    assert summary["law"] == MODEL.law.name and summary["edge"] == plan.arrays[0].model.edge
    prov.infos[1] = [_Info(30, False)]
    assert prov.summary("out.fits")["converged"] is False
    couple = Provenance(plan, RunSettings("couple"))
    couple.infos[1] = [None]
    assert (couple.summary("x")["iterations"], couple.summary("x")["converged"]) == (0, None)
