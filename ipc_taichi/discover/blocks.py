"""The data of a lab file prepared for the search: same-shape pairs stacked
into 3-D blocks, and the Gaussian likelihood of the data under a model.

:class:`PairBlocks` predicts each block through a
:class:`~ipc_taichi.discover.model.DetectorModel`, whitens residuals, computes
the deviance (:func:`deviance`, the response map's correlation between the
pairs of a file written out exactly) and the noise floor (fresh simulations
of the model against its own prediction).
"""

from dataclasses import dataclass, replace

import numpy as np

from ..errors import IPCInputError
from .diagnostics import (
    after_images,
    dipoles,
    fill_scene,
    find_probes,
    gap,
    pair_correlation,
    probe_masks,
    residual,
    residual_vs_signal,
    residuals_by_probe,
    stacked_windows,
    valid_mask,
)
from .effects import EFFECTS
from .sampling import block_sum, isolated_points

__all__ = ["PairBlocks", "Block", "deviance"]


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


@dataclass(frozen=True)
class Block:
    """The pairs of one shape and one SCENE sampling, stacked ``(K, ny, nx)``.

    ``scenes`` holds the pixels' totals (what the diagnostics look at),
    ``source`` what the model is given: the sub-pixel SCENE, ``(K, N ny, N
    nx)``, where ``oversample`` ``N`` > 1, else the same array as ``scenes``;
    ``measured`` is 0 outside ``valid``.
    """

    scenes: np.ndarray
    measured: np.ndarray
    valid: np.ndarray
    source: np.ndarray
    oversample: int = 1


@dataclass
class PairBlocks:
    """Prepared data: the pairs of a lab file as :class:`Block` records, and
    ``n``, the number of valid pixels in all of them."""

    blocks: list
    n: int

    @classmethod
    def from_lab(cls, lab):
        groups = {}
        for pair in lab.pairs:
            # a NaN sub-pixel makes its pixel's total NaN: a bad scene pixel
            total = block_sum(pair.scene, pair.oversample)
            valid = valid_mask(total, pair.measured)
            if not valid.any():
                raise IPCInputError(f"{lab.path}[MEASURED,{pair.extver}]: no valid pixel left "
                                    "after masking NaNs and the border")
            filled = fill_scene(pair.scene)
            groups.setdefault((pair.measured.shape, pair.oversample), []).append(
                (block_sum(filled, pair.oversample), np.where(valid, pair.measured, 0.0), valid,
                 filled))
        blocks = []
        for (_, n), items in groups.items():
            scenes, measured, valid, filled = (np.stack(a) for a in zip(*items))
            blocks.append(Block(scenes, measured, valid, scenes if n == 1 else filled, n))
        return cls(blocks, int(sum(b.valid.sum() for b in blocks)))

    def without_single_pixel_sources(self):
        """These blocks less the pixels where a pixel-total SCENE cannot say
        where the light lies and an effect that moves charge by a fraction of
        a pixel depends on it: each isolated single-pixel source (its 8
        neighbours each under :data:`~.sampling.POINT_CONTRAST` of it, e.g.
        a hot pixel, uniform across its pixel or at its centre alike) and its
        8 neighbours. ``None`` when no pixel-total block holds such a source
        (blocks with ``OVERSAMP`` say where their light is: kept whole)."""
        from scipy.ndimage import binary_dilation

        out, dropped = [], 0
        for b in self.blocks:
            if b.oversample > 1:
                out.append(b)
                continue
            spots = isolated_points(b.scenes) > 0
            near = binary_dilation(spots, structure=np.ones((1, 3, 3), dtype=bool))
            keep = b.valid & ~near
            dropped += int((b.valid & near).sum())
            out.append(replace(b, valid=keep, measured=np.where(keep, b.measured, 0.0)))
        if not dropped:
            return None
        return PairBlocks(out, int(sum(b.valid.sum() for b in out)))

    def probes(self):
        """Per frame (blocks in order) the probes of its SCENE
        (:func:`~.diagnostics.find_probes`) and their masks
        (:func:`~.diagnostics.probe_masks`), as ``(probes, masks)``."""
        probes, masks = [], []
        for b in self.blocks:
            for s, v in zip(b.scenes, b.valid):
                probes.append(find_probes(s, v))
                masks.append(probe_masks(s, v, probes[-1]))
        return probes, masks

    def diagnostics(self, model, probes, masks, parts=None):
        """What the report and the figures show of ``model``'s residuals
        (``probes`` and ``masks`` those of :meth:`probes`): the residual maps
        and means, the stacked windows, the residual and chi-square against
        signal, the gap, the residuals by probe, dipoles, after-images and the
        correlation between pairs."""
        res, means = self.residuals(model, parts)
        stacks, counts = stacked_windows(res, probes)
        centres, mean_r, mean_r2, n = residual_vs_signal(res, means)
        per_block, i = [], 0
        for b in self.blocks:
            per_block.append(res[i:i + len(b.scenes)])
            i += len(b.scenes)
        return {"residuals": res, "means": means, "stacks": stacks, "counts": counts,
                "signal": centres, "mean_residual": mean_r, "mean_residual2": mean_r2,
                "signal_counts": n, "gap": gap(res), "by_probe": residuals_by_probe(res, masks),
                "dipoles": dipoles(res, probes),
                "after_images": after_images(per_block, [b.scenes for b in self.blocks],
                                             [b.valid for b in self.blocks]),
                "pair_correlation": pair_correlation(per_block)}

    def inputs(self, model):
        """Per block what ``model`` is given, ``(scene, oversample)``: the
        sub-pixel SCENE only when the model has an effect that uses it
        (:attr:`~.record.Effect.subpixel`); otherwise the pixels' totals, the
        same numbers at a 25th of the work for ``N = 5``."""
        if not any(EFFECTS[e].subpixel for e in model.effects):
            return [(b.scenes, 1) for b in self.blocks]
        return [(b.source, b.oversample) for b in self.blocks]

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
        for (s, n), b, sd in zip(self.inputs(model), self.blocks, sds):
            out.append(((b.measured - model.expected(s, n)) / sd)[b.valid])
        return np.concatenate(out)

    def residuals(self, model, parts=None):
        """Per-frame residual maps (NaN outside valid) and expected means."""
        parts = parts or self.predict(model)
        res, means = [], []
        for (mean, _, _), var, b in zip(parts, self.total_variance(model, parts), self.blocks):
            res.extend(residual(b.measured, mean, var, b.valid))
            means.extend(mean)
        return res, means

    def deviance(self, model, parts, response_variance=None, read_variance=None):
        """:func:`deviance` of the data under ``model`` (``parts`` its prediction);
        the response and read variances may be overridden (noise-effect fits)."""
        u = model.response_variance() if response_variance is None else response_variance
        shift = 0.0 if read_variance is None else read_variance - model.read_variance()
        return deviance([b.measured - mean for (mean, _, _), b in zip(parts, self.blocks)],
                        [var + shift for _, var, _ in parts], [a for _, _, a in parts],
                        [b.valid for b in self.blocks], u)

    def floor(self, model, rng, n_sim, parts=None):
        """Gap of ``n_sim`` fresh simulations of ``model`` against its own prediction.

        Returns ``(mean, standard deviation, per-signal-bin mean chi-square)``.
        """
        parts = parts or self.predict(model)
        variances = self.total_variance(model, parts)
        gaps, per_bin = [], []
        for _ in range(n_sim):
            res, means = [], []
            for (s, n), b, (mean, _, _), var in zip(self.inputs(model), self.blocks, parts,
                                                    variances):
                res.extend(residual(model.simulate(s, rng, n), mean, var, b.valid))
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

