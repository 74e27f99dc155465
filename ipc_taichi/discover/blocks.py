"""The data of a lab file prepared for the search: same-shape pairs stacked
into 3-D blocks, and the Gaussian likelihood of the data under a model.

:class:`PairBlocks` predicts each block through a
:class:`~ipc_taichi.discover.model.DetectorModel`, whitens residuals, computes
the deviance (:func:`deviance`, the response map's correlation between the
pairs of a file written out exactly) and the noise floor (fresh simulations
of the model against its own prediction).
"""

from dataclasses import dataclass

import numpy as np

from ..errors import IPCInputError
from .diagnostics import fill_scene, gap, residual, residual_vs_signal, valid_mask
from .model import SUBPIXEL_EFFECTS
from .sampling import block_sum

__all__ = ["PairBlocks", "deviance"]


def deviance(residuals, variances, scales, valids, response_variance):
    """``-2 ln L`` (up to a constant) of Gaussian residuals, summed over blocks.

    Each block holds the pairs of one shape, ``(K, ny, nx)``: ``residuals``
    ``MEASURED - mean``, ``variances`` the independent (shot + read)
    variance, ``scales`` the response scale ``a`` (the charge a unit
    response change moves, through IPC: :meth:`DetectorModel.predict_parts`).
    A response map of variance ``u`` adds ``u a_k a_l`` to the covariance
    of pairs ``k, l`` at one pixel: a rank-one term, so per pixel
    (Sherman-Morrison, matrix determinant lemma)
    ``sum r^2/v - u b^2/(1 + u c) + sum ln v + ln(1 + u c)`` with
    ``b = sum r a / v`` and ``c = sum a^2 / v``.
    """
    total = 0.0
    u = float(response_variance)
    for r, v, mu, w in zip(residuals, variances, scales, valids):
        v = np.where(w, np.maximum(v, 1e-12), 1.0)
        r = np.where(w, r, 0.0)
        mu = np.where(w, mu, 0.0)
        total += float(np.sum(r * r / v) + np.sum(np.log(v)[w]))
        if u > 0:
            b = np.sum(r * mu / v, axis=0)
            c = np.sum(mu * mu / v, axis=0)
            total += float(np.sum(np.log1p(u * c) - u * b * b / (1.0 + u * c)))
    return total


@dataclass
class PairBlocks:
    """Prepared data: pairs of one shape and one SCENE sampling stacked into
    3-D blocks.

    ``scenes`` holds the pixels' totals (what the diagnostics look at),
    ``sources`` what the model is given: the sub-pixel SCENE where the file
    has one (``oversample`` > 1), else the same array as ``scenes``.
    """

    scenes: list
    measured: list
    valid: list
    n: int
    sources: list = None
    oversample: list = None

    def __post_init__(self):
        if self.sources is None:
            self.sources = list(self.scenes)
        if self.oversample is None:
            self.oversample = [1] * len(self.scenes)

    @classmethod
    def from_lab(cls, lab):
        groups = {}
        for (ver, scene, measured), n in zip(lab.pairs, lab.oversample):
            # a NaN sub-pixel makes its pixel's total NaN: a bad scene pixel
            total = block_sum(scene, n)
            valid = valid_mask(total, measured)
            if not valid.any():
                raise IPCInputError(f"{lab.path}[MEASURED,{ver}]: no valid pixel left after "
                                    "masking NaNs and the border")
            filled = fill_scene(scene)
            groups.setdefault((measured.shape, n), []).append(
                (block_sum(filled, n), np.where(valid, measured, 0.0), valid, filled))
        scenes, measured, valid, sources, factors = [], [], [], [], []
        for (_, n), items in groups.items():
            scenes.append(np.stack([s for s, _, _, _ in items]))
            measured.append(np.stack([m for _, m, _, _ in items]))
            valid.append(np.stack([v for _, _, v, _ in items]))
            sources.append(scenes[-1] if n == 1 else np.stack([f for _, _, _, f in items]))
            factors.append(n)
        return cls(scenes, measured, valid, int(sum(v.sum() for v in valid)), sources, factors)

    def inputs(self, model):
        """Per block what ``model`` is given, ``(scene, oversample)``: the
        sub-pixel SCENE only when the model has an effect that uses it
        (:data:`~.model.SUBPIXEL_EFFECTS`); otherwise the pixels' totals, the
        same numbers at a 25th of the work for ``N = 5``."""
        if not SUBPIXEL_EFFECTS & set(model.effects):
            return [(s, 1) for s in self.scenes]
        return list(zip(self.sources, self.oversample))

    def predict(self, model):
        """Per block ``(mean, independent variance, response scale)``
        (:meth:`DetectorModel.predict_parts`)."""
        return [model.predict_parts(s, n) for s, n in self.inputs(model)]

    @staticmethod
    def total_variance(model, parts):
        """Per block the diagonal variance, response map included."""
        u = model.response_variance()
        return [var + u * a * a for _, var, a in parts]

    def whitened(self, model, sds):
        """Residual vector ``(M - mean) / sd`` over valid pixels, ``sds`` fixed."""
        out = []
        for (s, n), m, v, sd in zip(self.inputs(model), self.measured, self.valid, sds):
            out.append(((m - model.expected(s, n)) / sd)[v])
        return np.concatenate(out)

    def residuals(self, model, parts=None):
        """Per-frame residual maps (NaN outside valid) and expected means."""
        parts = parts or self.predict(model)
        res, means = [], []
        for (mean, _, _), var, m, v in zip(parts, self.total_variance(model, parts),
                                           self.measured, self.valid):
            res.extend(residual(m, mean, var, v))
            means.extend(mean)
        return res, means

    def deviance(self, model, parts, response_variance=None, read_variance=None):
        """:func:`deviance` of the data under ``model`` (``parts`` its prediction);
        the response and read variances may be overridden (noise-effect fits)."""
        u = model.response_variance() if response_variance is None else response_variance
        shift = 0.0 if read_variance is None else read_variance - model.read_variance()
        return deviance([m - mean for (mean, _, _), m in zip(parts, self.measured)],
                        [var + shift for _, var, _ in parts], [a for _, _, a in parts],
                        self.valid, u)

    def floor(self, model, rng, n_sim, parts=None):
        """Gap of ``n_sim`` fresh simulations of ``model`` against its own prediction.

        Returns ``(mean, standard deviation, per-signal-bin mean chi-square)``.
        """
        parts = parts or self.predict(model)
        variances = self.total_variance(model, parts)
        gaps, per_bin = [], []
        for _ in range(n_sim):
            res, means = [], []
            for (s, n), v, (mean, _, _), var in zip(self.inputs(model), self.valid, parts,
                                                    variances):
                res.extend(residual(model.simulate(s, rng, n), mean, var, v))
                means.extend(mean)
            gaps.append(gap(res))
            per_bin.append(residual_vs_signal(res, means)[2])
        chi2_bins = None
        if n_sim:
            per_bin = np.array(per_bin)
            seen = np.isfinite(per_bin).sum(axis=0)
            chi2_bins = np.where(seen > 0, np.nansum(per_bin, axis=0) / np.maximum(seen, 1),
                                 np.nan)
        return (float(np.mean(gaps)), float(np.std(gaps, ddof=1)) if n_sim > 1 else 0.0,
                chi2_bins)

