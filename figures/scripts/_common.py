"""Shared helpers of the figure scripts: paths, atomic writes, progress, plot style.

Data scripts (``data_*.py``) run one seeded experiment each and write
``figures/data/<NN>_<name>.npz`` plus a Markdown fragment
``figures/data/<NN>_<name>.results.md`` (our numbers beside the paper's);
plot scripts (``plot_*.py``) only read those files and write ``figures/*.png``.
"""

import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # this checkout's packages, not another install

from ipc_taichi.fitsio import atomic_output  # noqa: E402

FIGURES = ROOT / "figures"
DATA = FIGURES / "data"


def save_npz(name, **arrays):
    """Write ``figures/data/<name>.npz`` atomically."""
    import numpy as np

    DATA.mkdir(parents=True, exist_ok=True)
    with atomic_output(str(DATA / f"{name}.npz"), overwrite=True) as tmp:
        np.savez(tmp, **arrays)


def load_npz(name):
    import numpy as np

    path = DATA / f"{name}.npz"
    if not path.exists():
        sys.exit(f"{path}: missing; run its data script first (make -C figures)")
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def save_json(name, obj):
    DATA.mkdir(parents=True, exist_ok=True)
    with atomic_output(str(DATA / f"{name}.json"), overwrite=True) as tmp:
        with open(tmp, "w") as fh:
            json.dump(obj, fh, indent=1, sort_keys=True)


def load_json(name):
    path = DATA / f"{name}.json"
    if not path.exists():
        sys.exit(f"{path}: missing; run its data script first (make -C figures)")
    with open(path) as fh:
        return json.load(fh)


def write_results(name, text):
    """Write the Markdown fragment ``figures/data/<name>.results.md`` atomically."""
    DATA.mkdir(parents=True, exist_ok=True)
    with atomic_output(str(DATA / f"{name}.results.md"), overwrite=True) as tmp:
        with open(tmp, "w") as fh:
            fh.write(text.rstrip() + "\n")


def progress(iterable, desc, total=None):
    """A tqdm progress bar on stderr (quiet when stderr is not a terminal and
    ``IPC_FIGURES_PROGRESS=0``)."""
    from tqdm import tqdm

    disable = os.environ.get("IPC_FIGURES_PROGRESS", "1") == "0"
    return tqdm(iterable, desc=desc, total=total, file=sys.stderr, disable=disable,
                mininterval=1.0, ncols=80)


def pyplot():
    """matplotlib.pyplot with a non-interactive backend and a common style."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": 110, "savefig.dpi": 110, "font.size": 10,
                         "axes.grid": True, "grid.alpha": 0.3,
                         "axes.titlesize": 10.5})
    return plt


def savefig(fig, name):
    """Write ``figures/<name>`` atomically and close the figure."""
    import matplotlib.pyplot as plt

    with atomic_output(str(FIGURES / name), overwrite=True) as tmp:
        fig.savefig(tmp, bbox_inches="tight")
    plt.close(fig)
    print(f"wrote figures/{name}")
