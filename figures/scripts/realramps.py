"""The worked example of ``docs/discover.md`` ("Real ramps"): discover on the
real FGS GUIDER2 ACQ1 ramp (``tests/data``) from the model ``calibrate``
measures on the same file, as a user types it: calibrate, the symmetric
start, ``ramp-file`` without and with ``--remove-frame-offsets``, discover.
Writes ``figures/realramps_fgs_raw.png``, ``figures/realramps_fgs.png`` (the
ramp figure of each run) and ``figures/data/realramps_fgs*.json`` (the reports).
About 3 minutes on 2 CPU cores."""

import os
import shutil
import tempfile

from _common import DATA, FIGURES, ROOT

from ipc_taichi.cli import main as cli
from ipc_taichi.discover.jwstramps import symmetric_model
from ipc_taichi.fitsio import atomic_output

FGS = str(ROOT / "tests" / "data" / "jwst_fgs_guider2_acq1.fits")
STAR = "64:125,35:96"  # the guide star, which moves 0.3 px over the 6 integrations


def _keep(src, dst):
    with atomic_output(str(dst), overwrite=True) as tmp:
        shutil.copyfile(src, tmp)


def main():
    os.environ.setdefault("IPC_TAICHI_ARCH", "cpu")
    os.environ.setdefault("IPC_TAICHI_PRECISION", "f64")
    DATA.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        model = os.path.join(tmp, "fgs_model.json")
        start = os.path.join(tmp, "fgs_start.json")
        assert cli(["calibrate", "--darks", FGS, "--gain", "1.57", "-o", model]) == 0
        symmetric_model(model, start)
        for name, extra in (("realramps_fgs_raw", []),
                            ("realramps_fgs", ["--remove-frame-offsets"])):
            ramps = os.path.join(tmp, f"{name}.fits")
            report = os.path.join(tmp, f"{name}.json")
            figs = os.path.join(tmp, name)
            assert cli(["ramp-file", FGS, ramps, "--gain", "1.57", "--exclude", STAR]
                       + extra) == 0
            assert cli(["discover", ramps, "--model", start, "--report", report,
                        "--figures", figs]) == 0
            _keep(os.path.join(figs, "ramp_gap.png"), FIGURES / f"{name}.png")
            _keep(report, DATA / f"{name}.json")


if __name__ == "__main__":
    main()
