"""Figure of experiment 60: what flats and hot pixels report (reads data/60_field.npz)."""

import sys

from _common import load_npz, pyplot, savefig


def main(name):
    d = load_npz("60_field")
    plt = pyplot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.6))
    s, g = d["levels"] / 1e3, d["grid"] / 1e3
    ax.plot(g, 100 * d["law_diag"], "C0-", label="law on its diagonal, alpha(S, S)")
    ax.plot(g, 100 * d["law_zero"], "C3-", label="law beside a dark pixel, alpha(S, 0)")
    ax.plot(g, 100 * d["law_diag_plus_slope"], "C0:",
            label="alpha(S,S) + S d/dS alpha(S,S) (not what a flat sees here)")
    ax.errorbar(s, 100 * d["flat_alpha"], 100 * d["flat_alpha_err"], fmt="o", color="C0",
                ms=4, capsize=2, label="flat-field autocorrelation (simulated)")
    ax.errorbar(s, 100 * d["hot_alpha"], 100 * d["hot_alpha_err"], fmt="s", color="C3",
                ms=4, capsize=2, label="hot pixels on a dark frame (simulated)")
    ax.set_xlabel("signal S of the flat / of the hot pixel [ke-]")
    ax.set_ylabel("alpha [%]")
    ax.legend(fontsize=8)
    ax.set_title("donlon2018 law: a flat measures alpha(S, S), a hot pixel alpha(S, 0)")
    bx.plot(g, 100 * d["law_diag"], "C0-", label="a(S) (= donlon2018's alpha(S, S))")
    bx.plot(g, 100 * d["law_diag_plus_slope"], "C2--",
            label="a(S) + S a'(S): the linearised prediction")
    bx.errorbar(s, 100 * d["source_alpha"], 100 * d["source_alpha_err"], fmt="o", color="C2", ms=4,
                capsize=2, label="flat-field autocorrelation (simulated)")
    bx.set_xlabel("signal S of the flat [ke-]")
    bx.set_ylabel("alpha [%]")
    bx.legend(fontsize=8)
    bx.set_title("control: a law of the sending pixel alone, a(S)")
    fig.suptitle("IPC as laboratories measure it: 1024x1024 flats (Poisson + 10 e- read noise) and "
                 "isolated hot pixels,\nthrough the shared detector chain; nothing tuned; bars = "
                 "standard errors (beyond the paper)", fontsize=10.5)
    fig.tight_layout()
    savefig(fig, name)


if __name__ == "__main__":
    main(sys.argv[1])
