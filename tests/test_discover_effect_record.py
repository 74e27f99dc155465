"""An effect is one record: a toy effect registered here (the worked record of
``docs/discover.md``, "Adding an effect") is used by the model, the generator,
the command line and the search with no other edit, and leaves nothing behind."""

import numpy as np
import pytest

from ipc_taichi.cli import main
from ipc_taichi.discover import DetectorModel, discover
from ipc_taichi.discover.effects import (
    EFFECTS,
    chain_order,
    contradiction,
    implausible,
    register,
)
from ipc_taichi.discover.fitting import candidates
from ipc_taichi.discover.labdata import effect_params
from ipc_taichi.discover.model import CHAIN_ORDER
from ipc_taichi.discover.record import Effect, Param
from tests.discover_helpers import final


class UniformGain(Effect):
    """``gain_excess``: every pixel collects ``1 + g`` times its expected charge."""

    position = 3.5      # after dark current, before brighter-fatter
    on_pixels = True    # acts on the pixels' totals

    def collect(self, charge, p):
        charge.value = charge.value * (1.0 + p["gain_excess"])

    def contradiction(self, p):
        if p["gain_excess"] <= 0:
            return f"a gain below one ({p['gain_excess']:.4g})"
        return None

    def implausible(self, p, readnoise=None, cov=None):
        return "a gain 20 % off" if p["gain_excess"] > 0.2 else None

    def from_value(self, value, readnoise=None):
        return {"gain_excess": float(value)}


UNIFORM_GAIN = UniformGain("uniform_gain", "collection",
                           (Param("gain_excess", 0.0, -0.1, 0.5, 0.002),),
                           "every pixel collects more charge than SCENE says")


@pytest.fixture
def uniform_gain():
    unregister = register(UNIFORM_GAIN)
    try:
        yield UNIFORM_GAIN
    finally:
        unregister()


def _scene(n=24):
    s = np.full((n, n), 100.0)
    s[5, 5] = 40000.0
    s[15:20, 15:20] = 30000.0
    return s


def test_a_registered_record_is_the_model_and_leaves_nothing_behind(cpu, uniform_gain):
    order = chain_order()
    assert order.index("dark_current") + 1 == order.index("uniform_gain") \
        == order.index("brighter_fatter") - 1
    scene = _scene()
    gain = {"uniform_gain": {"gain_excess": 0.05}}
    model = DetectorModel("donlon2018", 10.0, effects=gain)
    np.testing.assert_array_equal(model.collected(scene), scene * 1.05)
    # an OVERSAMP scene is summed to the pixels before an effect on the pixels' totals
    fine = np.repeat(np.repeat(scene, 2, axis=0), 2, axis=1) / 4.0
    np.testing.assert_allclose(model.collected(fine, oversample=2), scene * 1.05, rtol=1e-14)
    np.testing.assert_array_equal(model.expected(scene),
                                  DetectorModel("donlon2018", 10.0).expected(scene * 1.05))
    # after dark current: the dark charge is amplified too
    dark = DetectorModel("donlon2018", 10.0, effects={"dark_current": {"dark_e": 10.0}, **gain})
    np.testing.assert_allclose(dark.collected(scene), (scene + 10.0) * 1.05, rtol=1e-14)
    assert "gain below one" in contradiction("uniform_gain", {"gain_excess": -0.01})
    assert contradiction("uniform_gain", {"gain_excess": 0.01}) is None
    assert implausible("uniform_gain", {"gain_excess": 0.3}) == "a gain 20 % off"
    assert "uniform_gain" in candidates(DetectorModel("donlon2018", 10.0))
    assert effect_params("uniform_gain", "0.03") == {"gain_excess": 0.03}
    with pytest.raises(ValueError, match="already in the vocabulary"):
        register(UNIFORM_GAIN)


def test_an_unregistered_record_is_gone():
    unregister = register(UNIFORM_GAIN)
    unregister()
    assert "uniform_gain" not in EFFECTS and chain_order() == CHAIN_ORDER
    with pytest.raises(ValueError, match="unknown effect"):
        DetectorModel("donlon2018", 10.0, effects={"uniform_gain": {"gain_excess": 0.05}})


def test_the_search_names_a_registered_effect(tmp_path, uniform_gain):
    path = tmp_path / "lab.fits"
    assert main(["simulate-lab", str(path), "--seed", "301", "--size", "80",
                 "--effect", "uniform_gain=0.03"]) == 0
    report = discover(str(path)).report
    assert report["missing_effects"] == ["uniform_gain"]
    params, errors = final(report, "uniform_gain")
    assert 0 < errors["gain_excess"] < 0.003
    assert abs(params["gain_excess"] - 0.03) < 3 * errors["gain_excess"]
    assert report["complete"] is True
    assert "uniform_gain" in report["chain_order"]
