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


def _ramp(reads=5, size=24, seed=3):
    """A small coupled ramp (reads, size, size) in electrons, up to about 40 ke-."""
    rng = np.random.default_rng(seed)
    rate = rng.uniform(100.0, 8000.0, (size, size))
    truth = np.cumsum(np.broadcast_to(rate, (reads, size, size)), axis=0)
    return np.stack([ipc_taichi.couple(t, model=MODEL) for t in truth])


def test_a_lost_read_of_a_warm_ramp_is_kept_alone(cpu):
    """Read 2 of a 5-read ramp all NaN: with warm starts it alone is left as
    it came (said once); the other reads are decoupled, equal to a cold run's
    to the stopping rule's tolerance (the run used to refuse the ramp)."""
    ramp = _ramp()
    ramp[2] = np.nan
    settings = RunSettings()
    with pytest.warns(UserWarning, match="frame 2: no finite, unmasked pixel"):
        warm, warm_infos = correct_frames(ramp, FramePlan(MODEL, ramp=True), settings)
    with pytest.warns(UserWarning, match="frame 2"):
        cold, cold_infos = correct_frames(ramp, FramePlan(MODEL), settings)
    assert np.isnan(warm[2]).all() and np.isnan(cold[2]).all()
    assert [getattr(i, "lost", None) is not None for i in warm_infos] == \
        [False, False, True, False, False]
    for k in (0, 1, 3, 4):
        assert warm_infos[k].converged
        assert np.abs(warm[k] - cold[k]).max() <= settings.tol * np.abs(cold[k]).max()
        assert np.abs(warm[k] - ramp[k]).max() > 10 * settings.tol * np.abs(cold[k]).max()
    assert [i.warm_start for i in warm_infos if not getattr(i, "lost", None)] == \
        [False, True, True, True]


def test_the_physical_range_pass_gives_the_rules_answer(cpu):
    """A frame whose least and largest charge are physical skips the per-pixel
    rules; one holding an unphysical or a NaN pixel takes them: each answer is
    the one of the rules (the unphysical pixel kept, counted; the NaN kept)."""
    frame = _ramp(1)[0]
    clean, _ = correct_frames(frame, FramePlan(MODEL), RunSettings())
    np.testing.assert_array_equal(clean, ipc_taichi.decouple(frame, model=MODEL))
    bad = frame.copy()
    bad[3, 4], bad[7, 7] = 5e6, np.nan
    with pytest.warns(UserWarning, match="1 unflagged pixel"):
        out, _ = correct_frames(bad, FramePlan(MODEL), RunSettings())
    assert out[3, 4] == 5e6 and np.isnan(out[7, 7])
    with np.errstate(invalid="ignore"):
        unphysical = bad > 1e6
    np.testing.assert_array_equal(out, ipc_taichi.decouple(bad, model=MODEL, mask=unphysical))


def test_the_answer_is_stored_straight_into_a_big_endian_float32_out(cpu):
    """A big-endian float32 ``out`` (a memory-mapped FITS array) gets the
    answer rounded from the run's precision, as a float64 out would give it
    after a cast; its reference border is copied from the data."""
    ramp = _ramp(3).astype(np.float32)
    out = np.zeros(ramp.shape, dtype=">f4")
    region = (slice(2, 22), slice(2, 22))
    plan = FramePlan(MODEL, region=region)
    correct_frames(ramp, plan, RunSettings(), out=out)
    wide, _ = correct_frames(ramp, plan, RunSettings())
    np.testing.assert_array_equal(out, wide.astype(np.float32))
    direct = np.zeros((20, 20), dtype=">f4")
    answer = ipc_taichi.decouple(ramp[0][region].astype(np.float64), model=MODEL, out=direct)
    assert answer is direct
    np.testing.assert_array_equal(direct, wide[0][region].astype(np.float32))


def test_auto_precision_follows_the_data(cpu):
    """``precision="auto"`` runs float32 data in f32 (within two float32 steps
    of the f64 answer) and float64 data in f64 (the f64 answer, bit for bit)."""
    from ipc_taichi.products.options import precision_for

    assert precision_for("auto", [np.dtype(">f4")]) == "f32"
    assert precision_for("auto", [np.float32, np.float64]) == "f64"
    assert precision_for("f64", [np.float32]) == "f64"
    ramp = _ramp(2)
    auto = RunSettings(precision="auto")
    try:
        by64, infos64 = correct_frames(ramp, FramePlan(MODEL), auto)
        by32, infos32 = correct_frames(ramp.astype(np.float32), FramePlan(MODEL), auto)
    finally:
        ipc_taichi.init("cpu", "f64")
    assert [i.precision for i in infos64] == ["f64"] * 2
    assert [i.precision for i in infos32] == ["f32"] * 2
    np.testing.assert_array_equal(by64, correct_frames(ramp, FramePlan(MODEL), RunSettings())[0])
    steps = np.spacing(np.abs(ramp).astype(np.float32)).astype(np.float64)
    assert 0 < np.abs(by32 - by64).max() and (np.abs(by32 - by64) / steps).max() <= 2


def test_a_warm_start_carried_call_to_call_is_the_stacks(cpu):
    """Frames decoupled one call each with a :class:`WarmCarry` get the warm
    stack's answers bit for bit (the same starts, the same rule); after
    :meth:`~WarmCarry.reset` a frame starts from scratch (the cold answer)."""
    from ipc_taichi.decoupling import WarmCarry

    ramp = _ramp(4)
    stack, stack_infos = ipc_taichi.decouple(ramp, model=MODEL, warm_start=True,
                                             full_output=True)
    carry = WarmCarry()
    calls = [ipc_taichi.decouple(f, model=MODEL, warm_start=carry, full_output=True)
             for f in ramp]
    np.testing.assert_array_equal(np.stack([a for a, _ in calls]), stack)
    assert [i.warm_start for _, i in calls] == [i.warm_start for i in stack_infos] == \
        [False, True, True, True]
    assert [i.iterations for _, i in calls] == [i.iterations for i in stack_infos]
    assert stack_infos[3].iterations < ipc_taichi.decouple(ramp[3], model=MODEL,
                                                           full_output=True)[1].iterations
    carry.reset()
    again, info = ipc_taichi.decouple(ramp[3], model=MODEL, warm_start=carry, full_output=True)
    assert not info.warm_start
    np.testing.assert_array_equal(again, ipc_taichi.decouple(ramp[3], model=MODEL))


def test_a_loose_out_on_the_device_path_gets_the_same_answer(cpu):
    """The device path (its Taichi buffers, run on the CPU) fills a
    big-endian float32 window ``out`` by one copy at the end: the host path's
    answer (to rounding: another layout), and ``out`` is what is returned."""
    from ipc_taichi import engine

    frame = _ramp(1)[0]
    host = np.zeros((30, 30), dtype=">f4")[2:26, 3:27]
    ipc_taichi.decouple(frame, model=MODEL, out=host)
    device = np.zeros((30, 30), dtype=">f4")[2:26, 3:27]
    with engine.device_buffers():
        assert ipc_taichi.decouple(frame, model=MODEL, out=device) is device
    np.testing.assert_allclose(device, host, rtol=1e-6)  # the layouts agree to rounding
    assert host.any() and np.abs(host - frame).max() > 1.0
