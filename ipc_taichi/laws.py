"""Coupling laws alpha(S, N): the fraction of a pixel's signal S that couples
onto a neighbour whose signal is N.

Laws
----
``donlon2018``
    ``alpha(S,N) = 0.4 exp(-|S-N|/20000) + 0.4 exp(-sqrt(S^2+N^2)/(20000 sqrt2)) + 0.65`` [%].
    This is the form that reproduces every table and worked-example number of
    Donlon, Ninkov & Baum (JATIS 2018) and the authors' own code; the printed
    equation (their Eq. 7) has ``10000 sqrt2`` in the second exponent instead
    (see ``docs/reference.md`` section 1).
``donlon2018_printed``
    The printed Eq. 7, with ``10000 sqrt2``. Its minimum over 0..60000 e- is
    0.676 %, closer to the abstract's "0.68 %" than the default's 0.718 %.
``constant:<alpha>``
    A signal-independent coupling (fraction, e.g. ``constant:0.0125``); with
    nearest-neighbour geometry this is the classic 3x3 IPC kernel.
:class:`ParametricLaw`
    The family ``amp_diff exp(-|S-N|/scale_diff) +
    amp_level exp(-sqrt(S^2+N^2)/scale_level) + floor`` (fractions). All three
    laws above are members. Its coefficients are run-time kernel arguments:
    changing them never recompiles a kernel.
:class:`TabulatedLaw`
    ``alpha`` sampled on a uniform signal grid (a 2-D table, or a user
    callable sampled onto one) and looked up bilinearly inside the kernel;
    signals outside the grid are clamped to its edge.

Every law is symmetric, ``alpha(S,N) = alpha(N,S)``, which is what makes the
forward model conserve charge. Laws are validated on construction (finite,
non-negative, symmetric) and against a geometry before use (small enough for
the Jacobi iteration to contract, see :func:`check_convergence`).
"""

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import LawError

__all__ = [
    "ParametricLaw",
    "TabulatedLaw",
    "donlon2018",
    "donlon2018_printed",
    "constant",
    "get_law",
    "check_convergence",
    "LAW_NAMES",
]

LAW_NAMES = ("donlon2018", "donlon2018_printed", "constant:<alpha>", "parametric:<a,sd,b,sl,c>",
             "table:<file.npz>")


@dataclass(frozen=True)
class ParametricLaw:
    """The parametric law: ``alpha(S,N) = amp_diff*exp(-|S-N|/scale_diff) +
    amp_level*exp(-sqrt(S^2+N^2)/scale_level) + floor``.

    All values are fractions (0.0065 means 0.65 %); scales are in the signal's
    units (electrons or DN, whatever the frame holds).
    """

    amp_diff: float
    scale_diff: float
    amp_level: float
    scale_level: float
    floor: float
    name: str = "parametric"
    kind = "parametric"

    def __post_init__(self):
        values = (self.amp_diff, self.scale_diff, self.amp_level, self.scale_level, self.floor)
        if not all(math.isfinite(float(v)) for v in values):
            raise LawError(f"law {self.name!r}: coefficients must be finite, got {values}")
        if self.scale_diff <= 0 or self.scale_level <= 0:
            raise LawError(f"law {self.name!r}: scales must be > 0, got "
                           f"scale_diff={self.scale_diff}, scale_level={self.scale_level}")
        if self.min_alpha() < 0:
            raise LawError(f"law {self.name!r}: alpha can be negative "
                           f"(lower bound {self.min_alpha():.3g}); coupling fractions must be >= 0")

    def alpha(self, signal, neighbour, out=None, work=None):
        """Coupling fraction for signal ``signal`` next to ``neighbour`` (NumPy, broadcasting).

        This is the one NumPy evaluation of the formula. ``out`` and ``work``
        (float64 arrays of the broadcast shape) make it allocation-free, for
        loops that evaluate it many times (the benchmark's NumPy peer).
        """
        s = np.asarray(signal, dtype=np.float64)
        n = np.asarray(neighbour, dtype=np.float64)
        shape = np.broadcast_shapes(s.shape, n.shape)
        out = np.empty(shape) if out is None else out
        work = np.empty(shape) if work is None else work
        # amp_level exp(-sqrt(S^2 + N^2) / scale_level), with out as scratch
        np.multiply(n, n, out=out)
        np.multiply(s, s, out=work)
        np.add(work, out, out=work)
        np.sqrt(work, out=work)
        np.divide(work, -self.scale_level, out=work)
        np.exp(work, out=work)
        np.multiply(work, self.amp_level, out=work)
        # amp_diff exp(-|S - N| / scale_diff)
        np.subtract(s, n, out=out)
        np.abs(out, out=out)
        np.divide(out, -self.scale_diff, out=out)
        np.exp(out, out=out)
        np.multiply(out, self.amp_diff, out=out)
        np.add(out, work, out=out)
        np.add(out, self.floor, out=out)
        return out if out.ndim else out[()]

    def max_alpha(self):
        """An upper bound of alpha over all signals (exact when amplitudes >= 0)."""
        return max(self.amp_diff, 0.0) + max(self.amp_level, 0.0) + self.floor

    def min_alpha(self):
        """A lower bound of alpha over all signals."""
        return min(self.amp_diff, 0.0) + min(self.amp_level, 0.0) + self.floor

    def kernel_params(self):
        """The 5 run-time kernel arguments (reciprocal scales: the kernel multiplies)."""
        return np.array([self.amp_diff, 1.0 / self.scale_diff, self.amp_level,
                         1.0 / self.scale_level, self.floor], dtype=np.float64)

    def with_values(self, **changes):
        """A copy with some coefficients changed (same kernel, no recompilation)."""
        values = {k: getattr(self, k) for k in
                  ("amp_diff", "scale_diff", "amp_level", "scale_level", "floor", "name")}
        values.update(changes)
        return ParametricLaw(**values)

    def describe(self):
        return (f"{self.name}: {self.amp_diff:g}*exp(-|S-N|/{self.scale_diff:g}) + "
                f"{self.amp_level:g}*exp(-sqrt(S^2+N^2)/{self.scale_level:g}) + {self.floor:g}")


@dataclass(frozen=True, eq=False)
class TabulatedLaw:
    """alpha on a uniform signal grid, bilinear in between, clamped outside.

    Parameters
    ----------
    signal_min, signal_step : float
        The grid is ``signal_min + k * signal_step``, ``k = 0 .. n-1``.
    table : (n, n) array
        ``table[k, l] = alpha(S_k, N_l)``; must be symmetric (``table == table.T``).
    """

    signal_min: float
    signal_step: float
    table: np.ndarray = field(repr=False)
    name: str = "table"
    kind = "table"

    def __post_init__(self):
        table = np.array(self.table, dtype=np.float64)
        if table.ndim != 2 or table.shape[0] != table.shape[1] or table.shape[0] < 2:
            raise LawError(f"law {self.name!r}: table must be square (n, n) with n >= 2, "
                           f"got shape {table.shape}")
        if not np.all(np.isfinite(table)):
            raise LawError(f"law {self.name!r}: table holds {np.sum(~np.isfinite(table))} "
                           "non-finite values")
        if not (math.isfinite(self.signal_min) and math.isfinite(self.signal_step)
                and self.signal_step > 0):
            raise LawError(f"law {self.name!r}: signal grid needs finite signal_min and "
                           f"signal_step > 0, got {self.signal_min}, {self.signal_step}")
        asym = np.max(np.abs(table - table.T))
        if asym > 1e-12 * max(np.max(np.abs(table)), 1e-300):
            raise LawError(f"law {self.name!r}: table is not symmetric (max |T - T^T| = "
                           f"{asym:.3g}); alpha(S,N) must equal alpha(N,S) to conserve charge")
        if table.min() < 0:
            raise LawError(f"law {self.name!r}: table has negative alpha ({table.min():.3g})")
        table.setflags(write=False)
        object.__setattr__(self, "table", table)

    @classmethod
    def from_callable(cls, func, signal_range=(0.0, 65535.0), n=257, name=None):
        """Sample a vectorised ``func(S, N) -> alpha`` on an ``n x n`` uniform grid."""
        lo, hi = (float(v) for v in signal_range)
        if not hi > lo:
            raise LawError(f"signal_range must be increasing, got {signal_range}")
        grid = np.linspace(lo, hi, int(n))
        s, nb = np.meshgrid(grid, grid, indexing="ij")
        table = np.asarray(func(s, nb), dtype=np.float64)
        if table.shape != s.shape:
            raise LawError(f"callable law returned shape {table.shape}, expected {s.shape}")
        return cls(lo, (hi - lo) / (int(n) - 1), table,
                   name=name or getattr(func, "__name__", "table"))

    @property
    def n(self):
        return self.table.shape[0]

    def alpha(self, signal, neighbour, out=None, work=None):
        """Bilinear lookup (NumPy), the same arithmetic as the kernel (``work`` unused)."""
        u = (np.asarray(signal, np.float64) - self.signal_min) / self.signal_step
        v = (np.asarray(neighbour, np.float64) - self.signal_min) / self.signal_step
        last = self.n - 1
        u = np.clip(u, 0.0, last)
        v = np.clip(v, 0.0, last)
        i0 = np.minimum(np.floor(u).astype(np.int64), last - 1)
        j0 = np.minimum(np.floor(v).astype(np.int64), last - 1)
        fu = u - i0
        fv = v - j0
        t = self.table
        a = ((1 - fu) * ((1 - fv) * t[i0, j0] + fv * t[i0, j0 + 1])
             + fu * ((1 - fv) * t[i0 + 1, j0] + fv * t[i0 + 1, j0 + 1]))
        if out is None:
            return a
        out[...] = a
        return out

    def max_alpha(self):
        return float(self.table.max())

    def min_alpha(self):
        return float(self.table.min())

    def kernel_params(self):
        return np.array([self.signal_min, 1.0 / self.signal_step, float(self.n - 1), 0.0, 0.0],
                        dtype=np.float64)

    def describe(self):
        return (f"{self.name}: table {self.n}x{self.n} over "
                f"[{self.signal_min:g}, {self.signal_min + (self.n - 1) * self.signal_step:g}]")


def donlon2018():
    """The paper's law in the form that reproduces its tables (20000*sqrt2)."""
    return ParametricLaw(0.004, 20000.0, 0.004, 20000.0 * math.sqrt(2.0), 0.0065,
                         name="donlon2018")


def donlon2018_printed():
    """The paper's Eq. 7 exactly as printed (10000*sqrt2 in the second exponent)."""
    return ParametricLaw(0.004, 20000.0, 0.004, 10000.0 * math.sqrt(2.0), 0.0065,
                         name="donlon2018_printed")


def constant(alpha):
    """A signal-independent coupling ``alpha`` (a fraction)."""
    try:
        alpha = float(alpha)
    except (TypeError, ValueError):
        raise LawError(f"constant law needs a number, got {alpha!r}") from None
    # scales are irrelevant (amplitudes are 0) but must be valid numbers
    return ParametricLaw(0.0, 1.0, 0.0, 1.0, alpha, name=f"constant:{alpha:g}")


def get_law(spec):
    """Turn a law specification into a law object.

    Parameters
    ----------
    spec : str, float, ParametricLaw, TabulatedLaw
        ``"donlon2018"``, ``"donlon2018_printed"``, ``"constant:0.0125"``,
        ``"parametric:amp_diff,scale_diff,amp_level,scale_level,floor"``,
        ``"table:FILE.npz"`` (arrays ``signal`` (uniform, increasing) and ``alpha``),
        a float (constant alpha) or a law object (returned unchanged).
    """
    if isinstance(spec, (ParametricLaw, TabulatedLaw)):
        return spec
    if isinstance(spec, (int, float, np.floating)) and not isinstance(spec, bool):
        return constant(spec)
    if not isinstance(spec, str):
        raise LawError(f"cannot make a coupling law from {type(spec).__name__} {spec!r}")
    name, _, arg = spec.strip().partition(":")
    name = name.lower()
    if name == "donlon2018" and not arg:
        return donlon2018()
    if name == "donlon2018_printed" and not arg:
        return donlon2018_printed()
    if name == "constant" and arg:
        return constant(arg)
    if name == "parametric" and arg:
        try:
            values = [float(v) for v in arg.split(",")]
        except ValueError:
            raise LawError(f"law {spec!r}: coefficients must be numbers") from None
        if len(values) != 5:
            raise LawError(f"law {spec!r}: needs 5 coefficients "
                           "amp_diff,scale_diff,amp_level,scale_level,floor")
        return ParametricLaw(*values, name=spec)
    if name == "table" and arg:
        return _load_table(arg)
    raise LawError(f"unknown coupling law {spec!r}; choose one of {', '.join(LAW_NAMES)}")


def _load_table(path):
    try:
        with np.load(path) as data:
            signal = np.asarray(data["signal"], np.float64)
            alpha = np.asarray(data["alpha"], np.float64)
    except (OSError, KeyError, ValueError) as exc:
        raise LawError(f"law table {path}: cannot read arrays 'signal' and 'alpha' "
                       f"({exc})") from None
    if signal.ndim != 1 or signal.size < 2:
        raise LawError(f"law table {path}: 'signal' must be 1-D with >= 2 values")
    step = np.diff(signal)
    if np.any(step <= 0) or np.ptp(step) > 1e-9 * abs(step.mean()):
        raise LawError(f"law table {path}: 'signal' must be uniform and increasing")
    return TabulatedLaw(float(signal[0]), float(step.mean()), alpha, name=f"table:{path}")


def check_convergence(law, geometry, scale=1.0):
    """Raise :class:`LawError` if ``law`` on ``geometry`` is too strong to decouple.

    The Jacobi update is ``S_q = M - L(S_{q-1})``. Linearised, each row of ``L``
    has absolute sum at most ``2 * max_alpha * W`` with ``W`` the total
    outgoing weight of the geometry (Gershgorin), so the iteration contracts
    when that is below 1. For the nearest-neighbour constant law this is the
    exact condition ``alpha < 1/8``. ``scale`` is the largest factor a map
    multiplies alpha by (:mod:`ipc_taichi.bondmap`).
    """
    bound = 2.0 * law.max_alpha() * geometry.total_weight() * float(scale)
    if not bound < 1.0:
        raise LawError(
            f"law {law.name!r} with geometry {geometry.describe()} is too strong for the "
            f"iteration to converge: 2*max(alpha)*sum(weights) = {bound:.3g} >= 1"
        )
    return bound
