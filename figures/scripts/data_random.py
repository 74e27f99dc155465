"""Experiment 30: the uniform 0..60000 random frame (paper section 3.2).

Coupled, decoupled (the paper's iteration), Lucy-Richardson and Wiener
restorations against the truth, at read noise 0, 10, ..., 100 RMS. The same
read-noise instance is added to the truth and the coupled frame (paper 3.1),
so ``coupled - truth`` is IPC alone. Lucy-Richardson and Wiener get the
constant-alpha kernel of :func:`analysis.deconvolution.effective_alpha`
(measured frame only); Wiener's balance is chosen per read-noise level as the
best of a grid *against the truth* (an oracle: its best case).
Writes data/30_random.npz and data/30_random.results.md.
"""

import numpy as np

from _common import progress, save_npz, write_results

import ipc_taichi
from analysis.deconvolution import effective_alpha, ipc_kernel, lucy_richardson, wiener_filter
from ipc_taichi.datasets import uniform_frame

SIZE = 512
SEED = 2018
READ_NOISE = np.arange(0, 101, 10)
LR_ITER = 30
BALANCES = (1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3)
METHODS = ("coupled", "decoupled", "lr", "wiener")
BINS = {"coupled": np.linspace(-2000, 2000, 161), "decoupled": np.linspace(-0.04, 0.04, 161),
        "lr": np.linspace(-800, 800, 161), "wiener": np.linspace(-800, 800, 161)}


def effective_plain_alpha(measured):
    """Unweighted mean of alpha over the frame's nearest-neighbour pairs."""
    law = ipc_taichi.get_law("donlon2018")
    pairs = [law.alpha(measured[:, :-1], measured[:, 1:]), law.alpha(measured[:-1], measured[1:])]
    return float(np.concatenate([p.ravel() for p in pairs]).mean())


def main():
    signal = uniform_frame(SIZE, seed=SEED)
    ideal = ipc_taichi.couple(signal)  # IPC before read noise
    mae = {m: [] for m in METHODS}
    bias = {m: [] for m in METHODS}
    hist, extremes, notes = {}, {}, {}
    for k, sigma in enumerate(progress(READ_NOISE, "random frame: read noise levels")):
        noise = np.random.default_rng(SEED + 1 + k).normal(0.0, sigma, signal.shape)
        truth = signal + noise
        coupled = ideal + noise
        decoupled, info = ipc_taichi.decouple(coupled, full_output=True)
        alpha = effective_alpha(coupled)
        kernel = ipc_kernel(alpha)
        lr, clipped = lucy_richardson(coupled, kernel, LR_ITER)
        trials = [(np.abs(wiener_filter(coupled, kernel, b) - truth).mean(), b) for b in BALANCES]
        _, balance = min(trials)
        wiener = wiener_filter(coupled, kernel, balance)
        restored = {"coupled": coupled, "decoupled": decoupled, "lr": lr, "wiener": wiener}
        for m in METHODS:
            err = restored[m] - truth
            mae[m].append(float(np.abs(err).mean()))
            bias[m].append(float(err.mean()))
            if sigma == 0:
                hist[m] = np.histogram(np.clip(err, BINS[m][0], BINS[m][-1]), BINS[m])[0]
                extremes[m] = (float(err.min()), float(err.max()))
        if sigma == 0:
            # how much the LR result depends on its two free choices
            plain = effective_plain_alpha(coupled)
            lr_plain, _ = lucy_richardson(coupled, ipc_kernel(plain), LR_ITER)
            lr_long, _ = lucy_richardson(coupled, kernel, 100)
            notes["alpha_plain"] = [plain]
            notes["mae_lr_plain"] = [float(np.abs(lr_plain - truth).mean())]
            notes["mae_lr_100"] = [float(np.abs(lr_long - truth).mean())]
        notes.setdefault("alpha", []).append(alpha)
        notes.setdefault("balance", []).append(balance)
        notes.setdefault("lr_clipped", []).append(clipped)
        notes.setdefault("iterations", []).append(info.iterations)

    arrays = dict(read_noise=READ_NOISE, size=np.array(SIZE), lr_iter=np.array(LR_ITER),
                  **{f"mae_{m}": np.array(mae[m]) for m in METHODS},
                  **{f"bias_{m}": np.array(bias[m]) for m in METHODS},
                  **{f"hist_{m}": hist[m] for m in METHODS},
                  **{f"bins_{m}": BINS[m] for m in METHODS},
                  **{f"extremes_{m}": np.array(extremes[m]) for m in METHODS},
                  **{k: np.array(v) for k, v in notes.items()})
    save_npz("30_random", **arrays)

    def fmt(v):
        return f"{v:.3g}" if abs(v) < 10 else f"{v:.1f}"

    rows = "\n".join(
        f"| {s} | {fmt(mae['coupled'][k])} | {fmt(mae['decoupled'][k])} | {fmt(mae['lr'][k])} | "
        f"{fmt(mae['wiener'][k])} | {notes['iterations'][k]} | {notes['balance'][k]:.0e} | "
        f"{notes['lr_clipped'][k]} |"
        for k, s in enumerate(READ_NOISE))
    slope = np.polyfit(READ_NOISE, mae["decoupled"], 1)
    write_results("30_random", f"""
## Random frame: decoupling vs Lucy-Richardson and Wiener (paper section 3.2)

Figures: `hist_coupled.png` (paper Fig. 3.2.2), `hist_decoupled.png` (3.2.1),
`hist_lr.png` (3.2.3), `hist_wiener.png` (not in the paper); `mae_coupled.png` (3.2.5),
`mae_decoupled.png` (3.2.4), `mae_lr.png` (3.2.6), `mae_wiener.png` (not in the paper).
Data: `data/30_random.npz` (`figures/scripts/data_random.py`).

Set-up: one {SIZE}x{SIZE} frame, each pixel uniform in [0, 60000) (seed {SEED}), law
`donlon2018`, 4 nearest neighbours, zero edge; the same Gaussian read-noise instance
added to truth and coupled frame. Decoupling: the paper's stopping rule (tol 1e-5,
at most 20 iterations). Lucy-Richardson: `skimage.restoration.richardson_lucy`,
{LR_ITER} iterations (100 iterations give MAE {notes['mae_lr_100'][0]:.1f} at zero noise), with
the 3x3 constant-alpha kernel alpha = {notes['alpha'][0] * 100:.4f} %, the signal-weighted
mean of alpha(M_p, M_q) over the measured frame's neighbour pairs (the plain mean,
{notes['alpha_plain'][0] * 100:.4f} %, gives LR MAE {notes['mae_lr_plain'][0]:.1f} at zero noise); data divided by the
frame maximum, `clip=False`, negative pixels set to 0 first (count in the table).
Wiener: `skimage.restoration.wiener` with the same kernel, balance picked per row
as the best of {', '.join(f'{b:g}' for b in BALANCES)} against the truth (its best case).

| quantity (zero read noise) | paper | ours |
|---|---|---|
| mean abs(coupled - true) | ~719 | {mae['coupled'][0]:.1f} |
| max abs(coupled - true) | ~3000 (overestimate) | {max(map(abs, extremes['coupled'])):.0f} (range {extremes['coupled'][0]:.0f} .. {extremes['coupled'][1]:.0f}) |
| max abs(decoupled - true) | ~0.075 | {max(map(abs, extremes['decoupled'])):.4f} |
| mean abs(decoupled - true) | (not given) | {mae['decoupled'][0]:.2g} |
| mean abs(LR - true) | ~134 (133.8) | {mae['lr'][0]:.1f} |
| max abs(LR - true) | ~1000 (overestimate) | {max(map(abs, extremes['lr'])):.0f} (range {extremes['lr'][0]:.0f} .. {extremes['lr'][1]:.0f}) |
| mean abs(Wiener - true) | (not in the paper) | {mae['wiener'][0]:.1f} |

| read noise RMS | MAE coupled (paper ~719, flat) | MAE decoupled (paper 0 -> 5, linear) | MAE LR (paper 133.8 -> 134.0) | MAE Wiener | decouple iterations | Wiener balance | pixels < 0 set to 0 for LR |
|---|---|---|---|---|---|---|---|
{rows}

Decoupled MAE is linear in read noise: slope {slope[0]:.4f} per RMS count (paper: ~0.05),
intercept {slope[1]:.3f}. Ordering at zero read noise: decoupled ({mae['decoupled'][0]:.2g})
<< LR ({mae['lr'][0]:.1f}) << coupled ({mae['coupled'][0]:.1f}).

Where ours differ. Our coupled MAE ({mae['coupled'][0]:.0f}) and maximum error
({max(map(abs, extremes['coupled'])):.0f}) agree with the independent reproduction quoted in
REFERENCE.md (534.8 and 1578 on 64x64), not with the paper's 719 and 3000. The worked
example, which we reproduce to the printed decimals, pins the law; the cause of the
difference is not known (the paper does not give the frame's size or seed). The LR MAE depends on the constant kernel given to it (see above); the
paper does not say which kernel it used. Our decoupled maximum error is below the
paper's 0.075 because we iterate in float64 with the analytic law, where the authors'
code used float32 and a 4-decimal lookup table (REFERENCE.md section 3).
""")


if __name__ == "__main__":
    main()
