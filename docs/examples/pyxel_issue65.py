"""The figure an answer on esa/pyxel #65 would show: Pyxel's simple_ipc against
ipc_taichi.pyxel.nonlinear_ipc (Donlon, Ninkov & Baum 2018) on a Pyxel CMOS detector.

A hot pixel of charge Q on a flat background of B electrons: the fraction of Q that
each nearest neighbour shows, (neighbour - B) / Q, for Q from 1e3 to 1e5 e- and three
backgrounds. simple_ipc's coupling is one number (here the law's value at 20000 e-);
the paper's law depends on the pixel's signal and its neighbours'. Run:

    IPC_TAICHI_ARCH=cpu python docs/examples/pyxel_issue65.py   # writes pyxel_issue65.png
"""

import os
import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from pyxel.detectors import CMOS, CMOSCharacteristics, CMOSGeometry, Environment  # noqa: E402
from pyxel.detectors.charge_to_volt_settings import ChargeToVoltSettings  # noqa: E402
from pyxel.models.charge_measurement import simple_ipc  # noqa: E402

from ipc_taichi.laws import get_law  # noqa: E402
from ipc_taichi.pyxel import nonlinear_ipc  # noqa: E402

CVF, N = 3.0e-6, 15
FIGURE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "pyxel_issue65.png")


def neighbour_fraction(model, charge, background):
    det = CMOS(geometry=CMOSGeometry(row=N, col=N), environment=Environment(temperature=40.0),
               characteristics=CMOSCharacteristics(
                   charge_to_volt=ChargeToVoltSettings(value=CVF)))
    det.empty()
    pixel = np.full((N, N), float(background))
    pixel[N // 2, N // 2] += charge
    det.pixel.array = pixel
    model(det)
    out = np.asarray(det.signal.array) / CVF
    return (out[N // 2, N // 2 + 1] - background) / charge


def main(path=FIGURE):
    warnings.simplefilter("ignore", DeprecationWarning)  # Pyxel 3.0.2's own
    q = np.geomspace(1e3, 1e5, 25)
    # the paper's alpha for a 20000 e- pixel beside an empty one
    alpha0 = float(np.ravel(get_law("donlon2018").alpha(np.array([20000.0]),
                                                         np.array([0.0])))[0])
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for b, style in ((0.0, "-"), (5000.0, "--"), (20000.0, ":")):
        ours = [neighbour_fraction(lambda d: nonlinear_ipc(d, reference_pixels=0), c, b)
                for c in q]
        ax.plot(q, np.array(ours) * 100, style, color="C0",
                label=f"nonlinear_ipc (donlon2018), background {b:g} e-")
    fixed = [neighbour_fraction(lambda d: simple_ipc(d, coupling=alpha0), c, 0.0) for c in q]
    ax.plot(q, np.array(fixed) * 100, color="C3", label=f"simple_ipc, coupling={alpha0:.4f}")
    ax.set_xscale("log")
    ax.set_xlabel("hot-pixel charge Q (e-)")
    ax.set_ylabel("nearest neighbour / Q (%)")
    ax.set_title("Pyxel CMOS: fixed vs signal-dependent IPC")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(path)


if __name__ == "__main__":
    main()
