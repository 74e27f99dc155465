"""Ramps made by Pyxel's own detector models, written in the discovery ramp format.

Independent of ipc_taichi: it imports pyxel, numpy, yaml and astropy only and writes
the FITS file itself from docs/discovery_format.md ("Ramps"). A 32x32 CMOS detector
(no reference pixels) is read non-destructively at ``TFRAME, 2 TFRAME, ...``; the light
is Pyxel's ``illumination`` (a background and bright patches, photons/s), its shot
noise ``shot_noise``, charge by ``simple_conversion`` and ``simple_collection``;
``output_node_noise`` gives each read its read noise (drawn afresh per read). One
effect at a time is added with Pyxel's model for it (``EFFECTS``). MEASURED is
``detector.signal`` divided by the conversion gain (electrons); SCENE is the rate in
e-/s, taken from a noiseless one-second Pyxel run of the same light.
"""

import copy
import os
import tempfile

import numpy as np
import yaml

CVF = 3.0e-6  # V/e-, the detector's charge_to_volt
READ_NOISE = 10.0  # e- RMS per read
SHAPE = (32, 32)
TFRAME = 3.0  # s
NREADS = 6
BACKGROUND = 100.0  # photons/s per pixel
# (level photons/s, size (rows, cols), centre (row, col)): 54 ke- at the last read
PATCHES = [(3000.0, (4, 4), (8, 8)), (2000.0, (3, 5), (22, 10)), (2500.0, (5, 3), (12, 23)),
           (1500.0, (2, 2), (24, 24))]

# Pyxel's own models for the effects, each (pipeline group, model entry)
EFFECTS = {
    "null": [],
    "persistence": [("charge_collection", {
        "name": "persistence", "func": "pyxel.models.charge_collection.simple_persistence",
        "arguments": {"trap_time_constants": [5.0], "trap_densities": [0.02]}})],
    "persistence_dark": [("charge_collection", {
        "name": "persistence", "func": "pyxel.models.charge_collection.simple_persistence",
        "arguments": {"trap_time_constants": [5.0], "trap_densities": [0.02]}})],
    "pink_noise": [("charge_measurement", {
        "name": "pink", "func": "pyxel.models.charge_measurement.correlated_pink_noise_cmos",
        "arguments": {"std": 6.0}})],
    "nonlinearity": [("charge_measurement", {
        # signal (V) -> signal: 1 - 0.0405 at 50 ke- (0.15 V)
        "name": "linearity", "func": "pyxel.models.charge_measurement.output_node_linearity_poly",
        "arguments": {"coefficients": [0.0, 1.0, -0.0405 / (5e4 * CVF)]}})],
    "ipc_null": [("ipc", {
        "name": "simple_ipc", "func": "pyxel.models.charge_measurement.simple_ipc",
        "arguments": {"coupling": 0.0125}})],
    "diagonal_ipc": [("ipc", {
        "name": "simple_ipc", "func": "pyxel.models.charge_measurement.simple_ipc",
        "arguments": {"coupling": 0.0125, "diagonal_coupling": 0.002}})],
    "anisotropic_ipc": [("ipc", {
        "name": "simple_ipc", "func": "pyxel.models.charge_measurement.simple_ipc",
        "arguments": {"coupling": 0.0125, "anisotropic_coupling": 0.003}})],
    "dark_current": [("charge_generation", {
        "name": "dark", "func": "pyxel.models.charge_generation.simple_dark_current",
        "arguments": {"dark_rate": 20.0}})],
}
# the starting law the file states: the constant part of Pyxel's kernel is known
# which integrations have the patches (else the background only); one when not named
LIGHTS = {"persistence": (True, True), "persistence_dark": (True, False)}
# Pyxel models with a generator of their own (numpy's default_rng(seed), fresh entropy when
# the seed is None): given the ramp's seed, so that a file is the same at every run
UNSEEDED = ("correlated_pink_noise_cmos",)
IPCLAW = {name: "constant:0.0125" for name in ("ipc_null", "diagonal_ipc", "anisotropic_ipc")}


def _config(effect, times, noise=True, patches=True, seed=None):
    light = [{"name": "background", "func": "pyxel.models.photon_collection.illumination",
              "arguments": {"level": BACKGROUND}}]
    for i, (level, size, centre) in enumerate(PATCHES if patches else []):
        light.append({"name": f"patch{i}", "func": "pyxel.models.photon_collection.illumination",
                      "arguments": {"level": level, "option": "rectangular",
                                    "object_size": list(size), "object_center": list(centre)}})
    if noise:
        light.append({"name": "shot", "func": "pyxel.models.photon_collection.shot_noise"})
    groups = {"photon_collection": light,
              "charge_generation": [{"name": "photoelectrons",
                                     "func": "pyxel.models.charge_generation.simple_conversion"}],
              "charge_collection": [{"name": "collection",
                                     "func": "pyxel.models.charge_collection.simple_collection"}],
              "charge_measurement": []}
    extra = copy.deepcopy(EFFECTS[effect]) if noise else []
    for _, model in extra:  # a generator of its own, unseeded unless told (default_rng(None))
        if model["func"].endswith(UNSEEDED):
            model["arguments"]["seed"] = seed
    measure = [m for g, m in extra if g == "ipc"] or [
        {"name": "measurement", "func": "pyxel.models.charge_measurement.simple_measurement"}]
    groups["charge_measurement"] += measure
    for group, model in extra:
        if group != "ipc":
            groups[group].append(model)
    if noise:
        groups["charge_measurement"].append({
            "name": "read_noise", "func": "pyxel.models.charge_measurement.output_node_noise",
            "arguments": {"std_deviation": READ_NOISE * CVF}})
    for models in groups.values():
        for m in models:
            m["enabled"] = True
    return {
        "exposure": {"readout": {"times": [float(t) for t in times], "non_destructive": True}},
        "cmos_detector": {
            "geometry": {"row": SHAPE[0], "col": SHAPE[1], "total_thickness": 5.0,
                         "pixel_vert_size": 18.0, "pixel_horz_size": 18.0, "pixel_scale": 0.11},
            "environment": {"temperature": 40.0},
            "characteristics": {"quantum_efficiency": 1.0, "charge_to_volt": {"value": CVF},
                                "pre_amplification": 1.0, "full_well_capacity": 1000000,
                                "adc_bit_resolution": 16, "adc_voltage_range": [0.0, 3.0]}},
        "pipeline": groups,
    }


def _load(config):
    import pyxel

    fd, path = tempfile.mkstemp(suffix=".yaml")
    try:
        with os.fdopen(fd, "w") as f:
            yaml.safe_dump(config, f)
        return pyxel.load(path)
    finally:
        os.remove(path)


def _run(cfg, detector=None):
    import pyxel

    cfg.running_mode.outputs = None
    detector = detector if detector is not None else cfg.detector
    result = pyxel.run_mode(mode=cfg.running_mode, detector=detector, pipeline=cfg.pipeline)
    return np.asarray(result["/bucket"]["signal"], dtype=np.float64) / CVF


def scene_rate(patches=True):
    """The light's rate (e-/s) as Pyxel makes it: one noiseless second."""
    return _run(_load(_config("null", [1.0], noise=False, patches=patches)))[0]


def pyxel_ramps(effect, seed):
    """The reads ``(n_ints, NREADS, ny, nx)`` in electrons of ``effect`` (a key of
    ``EFFECTS``), Pyxel's generators seeded through NumPy's global state; the
    integrations' light as ``LIGHTS`` says, all on the same detector object (so
    persistence's traps are kept from one integration to the next)."""
    times = TFRAME * np.arange(1, NREADS + 1)
    np.random.seed(seed)
    detector, reads = None, []
    for patches in LIGHTS.get(effect, (True,)):
        cfg = _load(_config(effect, times, patches=patches, seed=seed))
        detector = detector if detector is not None else cfg.detector
        reads.append(_run(cfg, detector))
    return np.stack(reads)


def write_ramp_file(path, reads, rates, ipclaw="constant:0"):
    """The discovery ramp format, written by astropy from the format document;
    ``rates`` one SCENE (e-/s) per integration."""
    from astropy.io import fits

    primary = fits.PrimaryHDU()
    primary.header["READNOIS"] = READ_NOISE
    primary.header["SHOTNOIS"] = True
    primary.header["IPCLAW"] = ipclaw
    hdus = [primary]
    for k, (ramp, rate) in enumerate(zip(reads, rates), start=1):
        scene = fits.ImageHDU(np.asarray(rate, dtype=np.float64), name="SCENE")
        scene.header["EXTVER"] = k
        meas = fits.ImageHDU(np.asarray(ramp, dtype=np.float64), name="MEASURED")
        meas.header["EXTVER"] = k
        meas.header["TFRAME"] = TFRAME
        meas.header["TFIRST"] = TFRAME
        hdus += [scene, meas]
    tmp = str(path) + ".tmp"
    fits.HDUList(hdus).writeto(tmp, overwrite=True)
    os.replace(tmp, path)
    return path


def make(effect, seed, path):
    """Write the ramp file of ``effect`` at ``seed``. Where Pyxel's ``simple_ipc``
    runs, the outer ring of pixels is NaN in MEASURED (a bad pixel, per the format):
    Pyxel convolves with ``boundary="fill"`` at the frame's mean charge
    (docs/pyxel.md), an edge rule the format does not state, so the ring is left
    out rather than judged."""
    rates = [scene_rate(patches) for patches in LIGHTS.get(effect, (True,))]
    reads = pyxel_ramps(effect, seed)
    if any(group == "ipc" for group, _ in EFFECTS[effect]):
        reads[..., [0, -1], :] = np.nan
        reads[..., :, [0, -1]] = np.nan
    return write_ramp_file(path, reads, rates, IPCLAW.get(effect, "constant:0"))
