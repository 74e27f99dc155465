"""Analysis studies for ipc_taichi: the paper's image simulation, PSF/FWHM study,
deconvolution comparison and photometry (Donlon, Ninkov & Baum 2018, sections 3-4).

One module per concept: :mod:`analysis.psf` (optical and effective PSFs),
:mod:`analysis.fwhm` (FWHM estimators), :mod:`analysis.simulate` (the
flow-chart image simulation), :mod:`analysis.deconvolution` (Lucy-Richardson
and Wiener baselines), :mod:`analysis.photometry` (photutils PSF fitting of
blended pairs), :mod:`analysis.photometry_forward` (IPC-aware forward-model
fitting), :mod:`analysis.binary` (the binary-star grid study) and
:mod:`analysis.field_ipc` (IPC as laboratories measure it: flat-field
autocorrelation and hot pixels). Taichi is only initialised when IPC is applied.

In the repository this package is the folder ``analysis/``; pip installs it as
``ipc_taichi_analysis`` (a top-level ``analysis`` would clash with users' own). Its
modules import each other relatively, so they work under either name.
"""
