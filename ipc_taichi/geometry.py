"""Coupling geometry: which neighbours a pixel couples to, and how strongly.

Convention (written once, used everywhere)
------------------------------------------
Images are indexed ``image[y, x]`` (row, column), 0-based. An offset
``(dy, dx)`` with weight ``w`` means: a pixel at ``(y, x)`` whose signal is
``S`` sends ``w * alpha(S, N) * S`` of its charge to the pixel at
``(y + dy, x + dx)`` (whose signal is ``N``), and loses the same amount.

With a constant law this is a **convolution** of the signal with the 3x3
(or 5x5) kernel ``K`` where ``K[c + dy, c + dx] = w * alpha`` and the centre
``K[c, c] = 1 - sum(w) * alpha``: ``M = scipy.ndimage.convolve(S, K)``.
(GalSim's ``applyIPC`` applies its kernel as a correlation, i.e. flipped.)
For a symmetric geometry (``w(d) == w(-d)``) the two are the same.

The geometry multiplies the law: the coupling between two pixels at offset
``d`` is ``weight(d) * alpha(S, N)``. Named terms:

- ``horizontal``: along a row, offsets ``(0, +-1)``.
- ``vertical``: along a column, offsets ``(+-1, 0)``.
- ``diagonal``: ``(+-1, +-1)``.
- ``second``: two steps along a row or column, ``(0, +-2)`` and ``(+-2, 0)``.

``horizontal != vertical`` is anisotropic coupling. Both the forward model
(:func:`ipc_taichi.couple`) and the decoupler use the same geometry object.
"""

from dataclasses import dataclass

import numpy as np

from .errors import GeometryError

__all__ = ["Geometry", "NEAREST"]

_MAX_REACH = 2


@dataclass(frozen=True)
class Geometry:
    """Directed coupling weights, one per offset ``(dy, dx)``.

    Use :meth:`nearest`, :meth:`terms`, :meth:`from_kernel`, or pass a
    mapping ``{(dy, dx): weight}``. Offsets reach at most 2 pixels.
    """

    weights: tuple  # ((dy, dx), w) pairs, sorted, w != 0

    def __init__(self, weights):
        if isinstance(weights, dict):
            items = weights.items()
        else:
            items = weights
        clean = {}
        for offset, w in items:
            try:
                dy, dx = (int(v) for v in offset)
                w = float(w)
            except (TypeError, ValueError):
                raise GeometryError(f"geometry entry {offset!r}: {w!r} is not "
                                    "((dy, dx), weight)") from None
            if (dy, dx) == (0, 0):
                raise GeometryError("geometry offset (0, 0) is the pixel itself")
            if max(abs(dy), abs(dx)) > _MAX_REACH:
                raise GeometryError(f"geometry offset {(dy, dx)} reaches beyond "
                                    f"{_MAX_REACH} pixels")
            if not np.isfinite(w) or w < 0:
                raise GeometryError(f"geometry weight for {(dy, dx)} must be finite and >= 0, "
                                    f"got {w}")
            if w != 0.0:
                clean[(dy, dx)] = clean.get((dy, dx), 0.0) + w
        if not clean:
            raise GeometryError("geometry has no non-zero weight")
        object.__setattr__(self, "weights", tuple(sorted(clean.items())))

    @classmethod
    def nearest(cls):
        """The paper's geometry: the 4 nearest neighbours, weight 1."""
        return cls.terms()

    @classmethod
    def terms(cls, horizontal=1.0, vertical=1.0, diagonal=0.0, second=0.0,
              second_horizontal=None, second_vertical=None):
        """A symmetric geometry from named terms (multipliers of alpha).

        ``second`` sets both second-neighbour terms unless ``second_horizontal``
        or ``second_vertical`` is given.
        """
        sh = second if second_horizontal is None else second_horizontal
        sv = second if second_vertical is None else second_vertical
        w = {}
        for d in ((0, 1), (0, -1)):
            w[d] = horizontal
        for d in ((1, 0), (-1, 0)):
            w[d] = vertical
        for d in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            w[d] = diagonal
        for d in ((0, 2), (0, -2)):
            w[d] = sh
        for d in ((2, 0), (-2, 0)):
            w[d] = sv
        return cls(w)

    @classmethod
    def from_kernel(cls, kernel, alpha=1.0):
        """Weights from a 3x3 or 5x5 kernel (centre ignored) divided by ``alpha``."""
        k = np.asarray(kernel, dtype=np.float64)
        if k.ndim != 2 or k.shape[0] != k.shape[1] or k.shape[0] not in (3, 5):
            raise GeometryError(f"kernel must be 3x3 or 5x5, got shape {k.shape}")
        c = k.shape[0] // 2
        return cls({(dy - c, dx - c): k[dy, dx] / alpha
                    for dy in range(k.shape[0]) for dx in range(k.shape[1])
                    if (dy, dx) != (c, c) and k[dy, dx] != 0})

    @classmethod
    def parse(cls, text):
        """From ``"horizontal=1,vertical=0.9,diagonal=0.1,second=0"`` (CLI form).

        Terms not named are zero: ``"vertical=1"`` couples along columns only
        (``"nearest"`` or an empty text is the paper's 4 neighbours)."""
        if text is None or not str(text).strip() or str(text).strip() == "nearest":
            return cls.nearest()
        kwargs = {}
        allowed = ("horizontal", "vertical", "diagonal", "second",
                   "second_horizontal", "second_vertical")
        for part in str(text).split(","):
            key, eq, value = part.partition("=")
            key = key.strip()
            if not eq or key not in allowed:
                raise GeometryError(f"geometry term {part!r}: expected NAME=VALUE with NAME in "
                                    f"{', '.join(allowed)}")
            try:
                kwargs[key] = float(value)
            except ValueError:
                raise GeometryError(f"geometry term {part!r}: {value!r} is not a number") from None
        kwargs.setdefault("horizontal", 0.0)
        kwargs.setdefault("vertical", 0.0)
        return cls.terms(**kwargs)

    def weight(self, dy, dx):
        return dict(self.weights).get((dy, dx), 0.0)

    def total_weight(self):
        """Sum of all outgoing weights (``4`` for nearest neighbours)."""
        return float(sum(w for _, w in self.weights))

    @property
    def symmetric(self):
        return all(self.weight(-dy, -dx) == w for (dy, dx), w in self.weights)

    @property
    def reach(self):
        """How many pixels away the furthest coupled neighbour is."""
        return max(max(abs(dy), abs(dx)) for (dy, dx), _ in self.weights)

    def half_stencil(self):
        """Offsets ``u`` with one representative per ``{u, -u}`` pair, and their
        weights ``(w(u), w(-u))``. This is what the kernels loop over."""
        pairs = {}
        for (dy, dx), _ in self.weights:
            u = (dy, dx) if (dy > 0 or (dy == 0 and dx > 0)) else (-dy, -dx)
            pairs[u] = (self.weight(*u), self.weight(-u[0], -u[1]))
        return tuple(sorted(pairs.items()))

    def kernel(self, alpha):
        """The convolution kernel for a constant ``alpha`` (see module docstring)."""
        r = max(self.reach, 1)
        k = np.zeros((2 * r + 1, 2 * r + 1))
        for (dy, dx), w in self.weights:
            k[r + dy, r + dx] = w * alpha
        k[r, r] = 1.0 - self.total_weight() * alpha
        return k

    def describe(self):
        if self == NEAREST:
            return "nearest"
        return ";".join(f"{dy:+d},{dx:+d}={w:g}" for (dy, dx), w in self.weights)


NEAREST = Geometry.terms()
