"""Seeded synthetic data: the frames the tests, the demo, the benchmark, the
figures and the discovery workflow are made from.

Every generator is deterministic for a given ``seed`` and returns new
``float64`` arrays in electrons of collected charge, ``image[y, x]``.

- :func:`worked_example`: the paper's worked example (its section 2.3), a
  2x2 star inside a 51x51 zero frame.
- :func:`uniform_frame`: the paper's random frame, uniform in ``[0, high)``.
- :func:`star_field`: Gaussian stars on a background (the benchmark's sky).
- :func:`gaussian_spot`, :func:`add_gaussian_spot`: a pixel-integrated
  circular Gaussian (the light of a small spot collected by square pixels).
- :func:`flat`, :func:`hot_pixels`: what laboratories measure IPC with.
"""

import math

import numpy as np
from scipy.special import ndtr

__all__ = ["WORKED_STAR", "WORKED_WINDOW", "worked_example", "uniform_frame", "star_field",
           "gaussian_spot", "add_gaussian_spot", "flat", "hot_pixels"]

WORKED_STAR = np.array([[2000.0, 4000.0], [4000.0, 10000.0]])
"""The worked example's 2x2 star [e-] (paper section 2.3)."""

WORKED_WINDOW = (slice(23, 27), slice(23, 27))
"""The 4x4 window of :func:`worked_example` the paper prints (star at its centre)."""


def worked_example():
    """The worked-example frame: 51x51 zeros with :data:`WORKED_STAR` at [24:26, 24:26].

    This is the authors' demonstration setup; the paper prints the window
    :data:`WORKED_WINDOW`. The numbers it reproduces are in ``docs/reference.md``.
    """
    truth = np.zeros((51, 51))
    truth[24:26, 24:26] = WORKED_STAR
    return truth


def uniform_frame(size, seed=2018, high=60000.0):
    """The paper's random frame: each pixel uniform in ``[0, high)`` e-, seeded."""
    return np.random.default_rng(seed).uniform(0.0, high, (size, size))


def star_field(size, seed=2018, n_per_mpix=2000, background=100.0, peak=(300.0, 60000.0)):
    """A seeded star field: point-sampled Gaussian stars (sigma 0.8-1.5 px),
    peaks log-uniform in ``peak`` [e-], on a flat ``background`` [e-]."""
    rng = np.random.default_rng(seed)
    frame = np.full((size, size), background)
    n = max(1, int(n_per_mpix * size * size / 1e6))
    ys, xs = rng.uniform(0, size, n), rng.uniform(0, size, n)
    peaks = np.exp(rng.uniform(np.log(peak[0]), np.log(peak[1]), n))
    sigmas = rng.uniform(0.8, 1.5, n)
    r = 6
    for y, x, a, s in zip(ys, xs, peaks, sigmas):
        y0, x0 = int(y), int(x)
        yy, xx = np.mgrid[max(0, y0 - r):min(size, y0 + r + 1),
                          max(0, x0 - r):min(size, x0 + r + 1)]
        frame[yy, xx] += a * np.exp(-((yy - y) ** 2 + (xx - x) ** 2) / (2 * s * s))
    return frame


def add_gaussian_spot(image, y0, x0, flux, fwhm, radius=4):
    """Add, in place, a circular Gaussian of total ``flux`` [e-] and ``fwhm``
    [px] centred at ``(y0, x0)``, integrated over each pixel's area (pixel
    ``(i, j)`` covers ``[i - 1/2, i + 1/2] x [j - 1/2, j + 1/2]``), within
    ``radius`` pixels of the nearest pixel centre; clipped at the frame edge."""
    sigma = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    r = int(radius)
    iy, ix = int(round(y0)), int(round(x0))
    ys = np.arange(iy - r, iy + r + 1)
    xs = np.arange(ix - r, ix + r + 1)
    py = ndtr((ys + 0.5 - y0) / sigma) - ndtr((ys - 0.5 - y0) / sigma)
    px = ndtr((xs + 0.5 - x0) / sigma) - ndtr((xs - 0.5 - x0) / sigma)
    spot = flux * np.outer(py, px)
    ny, nx = image.shape
    y0c, x0c = max(iy - r, 0), max(ix - r, 0)
    y1c, x1c = min(iy + r + 1, ny), min(ix + r + 1, nx)
    image[y0c:y1c, x0c:x1c] += spot[y0c - (iy - r):y1c - (iy - r), x0c - (ix - r):x1c - (ix - r)]
    return image


def gaussian_spot(shape, y0, x0, flux, fwhm, radius=4):
    """A zero frame of ``shape`` with one :func:`add_gaussian_spot`."""
    return add_gaussian_spot(np.zeros(shape), y0, x0, flux, fwhm, radius)


def flat(shape, level):
    """The expected charge of a flat field: ``level`` e- in every pixel (draw
    the shot noise with :func:`ipc_taichi.detector.collect`)."""
    return np.full(shape, float(level))


def hot_pixels(shape, n, level, background=0.0, seed=0, isolation=5):
    """Isolated hot pixels on a flat background (single-pixel events).

    ``n`` pixels of ``level`` e- (a number, or ``(low, high)`` for
    log-uniform levels) on ``background`` e-, at least ``isolation`` pixels
    from each other and from the frame edge (Chebyshev distance), so that
    each one's coupled neighbours are its own. Fewer than ``n`` are placed
    when the frame has no room.

    Returns
    -------
    image : ndarray
    positions : ndarray of int, shape (k, 2)
        ``(y, x)`` of each hot pixel.
    """
    rng = np.random.default_rng(seed)
    ny, nx = shape
    image = np.full(shape, float(background))
    taken = np.zeros(shape, dtype=bool)
    placed = []
    for _ in range(20 * int(n)):
        if len(placed) >= n:
            break
        y = int(rng.integers(isolation, ny - isolation)) if ny > 2 * isolation else -1
        x = int(rng.integers(isolation, nx - isolation)) if nx > 2 * isolation else -1
        if y < 0 or x < 0:
            break
        if taken[y, x]:
            continue
        taken[max(0, y - isolation):y + isolation + 1,
              max(0, x - isolation):x + isolation + 1] = True
        placed.append((y, x))
    positions = np.array(placed, dtype=int).reshape(-1, 2)
    if np.ndim(level) == 0:
        levels = np.full(len(positions), float(level))
    else:
        low, high = level
        levels = np.exp(rng.uniform(np.log(low), np.log(high), len(positions)))
    image[positions[:, 0], positions[:, 1]] = background + levels
    return image, positions
