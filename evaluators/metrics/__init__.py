"""Pure metrics and pictures: arrays in, numbers or PNG bytes out (a leaf package).

Submodules:

- :mod:`~evaluators.metrics.images`: FLIP (NVIDIA's implementation), PSNR, SSIM, MAE, MSE;
- :mod:`~evaluators.metrics.brdf`: BRDF-space SMAPE (Eq. 6 of the hybrid-BRDF paper), MAE;
- :mod:`~evaluators.metrics.tonemap`: tone mapping and the magma colour map;
- :mod:`~evaluators.metrics.brdf_view`: half/diff slices of BRDF tables as pictures;
- :mod:`~evaluators.metrics.figures`: matplotlib figures (curves, Pareto charts) as PNG.

It imports nothing of ours but :mod:`materials` and :mod:`storage` (import contracts).
"""

SUBMODULES: tuple[str, ...] = ("images", "brdf", "tonemap", "brdf_view", "figures")
