"""Tabulate Mitsuba 3 BSDFs and analytic sources into MERL tables.

Sampling convention: each bin ``(i_h, i_d, i_p)`` holds the BRDF at **one** direction pair,
its centre in the MERL coordinates (square-root theta_h, linear theta_d and phi_d), at
``phi_h = 0``: see :func:`materials.halfdiff.bin_directions`. Bins whose pair has
``wi.z <= 0`` or ``wo.z <= 0`` are set to :data:`materials.halfdiff.MISSING` (-1).

Mitsuba sources are evaluated in the vectorised ``llvm_ad_rgb`` variant (via
:func:`materials.backend.load_mitsuba`) in a single ``bsdf.eval`` call over all
bins plus the anisotropy and reciprocity probes. ``bsdf.eval`` returns ``f cos(theta_o)``;
the table stores ``f = eval / wo.z``, with ``wo.z`` taken from the float32 direction that
Mitsuba saw, so grazing bins keep full relative precision.

The MERL format is isotropic: a value must not depend on ``phi_h``. Every tabulation
re-evaluates a strided subset of bins at ``phi_h = pi/4`` and ``pi/2`` and reports the
largest relative difference as ``info["anisotropy_error"]``; above ``anisotropy_tol`` the
source is refused with ``ValueError`` unless ``allow_anisotropic=True``. The 180-bin layout
folds phi_d by reciprocity, so ``info["reciprocity_error"]`` reports the same statistic for
``f(wo, wi)`` against ``f(wi, wo)`` (informational).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from materials import halfdiff as hd
from storage.formats.merl import MerlTable

#: Default refusal threshold of the anisotropy check (relative difference).
ANISOTROPY_TOL = 1e-2
# Probe subset: every 3rd theta_h and theta_d bin and every 6th phi_d bin (27,000 bins).
_PROBE_STRIDE = (3, 3, 6)
_PROBE_PHI_H = (0.25 * np.pi, 0.5 * np.pi)
# Rows per call when tabulating numpy sources.
_ANALYTIC_CHUNK = 1 << 17

Evaluator = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _probe_pairs(phi_d_bins: int) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """Flat indices of the probe bins and their pairs rotated to each probe phi_h."""
    th, td, pd = hd.bin_centers(phi_d_bins)
    sh, sd, sp = _PROBE_STRIDE
    ih, id_, ip = np.meshgrid(
        np.arange(0, 90, sh), np.arange(0, 90, sd), np.arange(0, phi_d_bins, sp), indexing="ij"
    )
    flat = hd.flat_index(ih, id_, ip, phi_d_bins).ravel()
    pairs = [hd.from_halfdiff(th[ih], phi_h, td[id_], pd[ip]) for phi_h in _PROBE_PHI_H]
    return flat, pairs


def _relative_error(ref: np.ndarray, other: np.ndarray, valid: np.ndarray) -> float:
    """Max over valid rows of ``|a - b| / max(|a|, |b|, floor)``, floor = 1e-4 max|a|."""
    if not valid.any():
        return 0.0
    a, b = ref[valid], other[valid]
    floor = 1e-4 * max(float(np.max(np.abs(a))), 1e-12)
    return float(np.max(np.abs(a - b) / np.maximum(np.maximum(np.abs(a), np.abs(b)), floor)))


def _tabulate(
    evaluate: Evaluator,
    phi_d_bins: int,
    *,
    allow_anisotropic: bool,
    anisotropy_tol: float,
    source: str,
) -> tuple[MerlTable, dict[str, Any]]:
    wi, wo = hd.bin_directions(phi_d_bins)
    flat, rotated = _probe_pairs(phi_d_bins)
    n = len(wi)
    # One batch: all bins, the rotated probes, and the probes with wi and wo swapped.
    all_wi = np.concatenate([wi] + [p[0] for p in rotated] + [wo[flat]])
    all_wo = np.concatenate([wo] + [p[1] for p in rotated] + [wi[flat]])
    t0 = time.perf_counter()
    values = evaluate(all_wi, all_wo)
    eval_seconds = time.perf_counter() - t0
    above = (all_wi[:, 2] > 0) & (all_wo[:, 2] > 0)
    base = values[:n]
    probe_ref = base[flat]
    aniso, start = 0.0, n
    for _ in rotated:
        block = slice(start, start + len(flat))
        aniso = max(aniso, _relative_error(probe_ref, values[block], above[flat] & above[block]))
        start += len(flat)
    recip = _relative_error(probe_ref, values[start:], above[flat])
    info: dict[str, Any] = {
        "source": source,
        "phi_d_bins": phi_d_bins,
        "sampling": "bin centre in (sqrt theta_h, theta_d, phi_d), phi_h = 0",
        "below_horizon_bins": int(np.count_nonzero(~above[:n])),
        "anisotropy_error": aniso,
        "reciprocity_error": recip,
        "eval_seconds": eval_seconds,
    }
    if aniso > anisotropy_tol and not allow_anisotropic:
        raise ValueError(
            f"the {source} source is anisotropic (relative change {aniso:.3g} "
            f"when rotated about the normal, tolerance {anisotropy_tol:g}); "
            f"MERL tables are isotropic. Pass allow_anisotropic=True to "
            f"tabulate it anyway and record the error"
        )
    rgb = np.where(above[:n, None], base, hd.MISSING)
    table = MerlTable(rgb=rgb.reshape(90, 90, phi_d_bins, 3), phi_d_bins=phi_d_bins)
    return table, info


def mitsuba_evaluator(bsdf: Any) -> Evaluator:
    """A numpy evaluator ``(wi, wo) -> (N, 3)`` plain BRDF of a Mitsuba BSDF.

    ``bsdf`` is a Mitsuba plugin dict (``{"type": "roughconductor", ...}``) or a loaded
    ``mi.BSDF``. Each call is one vectorised ``bsdf.eval`` in the variant chosen by
    :func:`load_mitsuba`, in a surface interaction with normal ``(0, 0, 1)``; the result
    is ``eval / wo.z`` in float64, 0 where ``wi.z <= 0`` or ``wo.z <= 0``.
    """
    from materials.backend import load_mitsuba

    mi = load_mitsuba()
    variant = mi.variant()
    if not variant.startswith(("llvm_", "cuda_")) or "rgb" not in variant:
        raise RuntimeError(
            f"tabulation needs a vectorised RGB Mitsuba variant such as "
            f"llvm_ad_rgb, but Mitsuba runs {variant!r}; install libLLVM "
            f"(make setup) so that the LLVM backend can start"
        )
    import drjit as dr

    if isinstance(bsdf, Mapping):
        try:
            bsdf = mi.load_dict(dict(bsdf))
        except Exception as exc:  # Mitsuba raises plain RuntimeError/TypeError on bad dicts
            # the whole message on one line: its first line names the plugin, the next
            # ones the unreferenced properties
            text = " ".join(str(exc).split()) or repr(exc)
            raise ValueError(f"Mitsuba could not build the BSDF: {text}") from exc

    def evaluate(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        wi32 = np.ascontiguousarray(wi, dtype=np.float32)
        wo32 = np.ascontiguousarray(wo, dtype=np.float32)
        si = dr.zeros(mi.SurfaceInteraction3f, len(wi32))
        si.n = mi.Normal3f(0.0, 0.0, 1.0)
        si.sh_frame = mi.Frame3f(si.n)
        si.wi = mi.Vector3f(wi32[:, 0], wi32[:, 1], wi32[:, 2])
        value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo32[:, 0], wo32[:, 1], wo32[:, 2]))
        cosine = np.asarray(value, dtype=np.float64).T  # (3, N) -> (N, 3)
        cos_o = wo32[:, 2].astype(np.float64)
        above = (wi32[:, 2] > 0) & (cos_o > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(above[:, None], cosine / cos_o[:, None], 0.0)

    return evaluate


def tabulate_mitsuba(
    bsdf: Mapping[str, Any] | Any,
    *,
    phi_d_bins: int = 180,
    allow_anisotropic: bool = False,
    anisotropy_tol: float = ANISOTROPY_TOL,
) -> tuple[MerlTable, dict[str, Any]]:
    """Tabulate a Mitsuba 3 BSDF into a MERL table.

    Parameters
    ----------
    bsdf
        Mitsuba plugin dict or loaded ``mi.BSDF``.
    phi_d_bins
        180 (canonical) or 360.
    allow_anisotropic, anisotropy_tol
        See the module docstring.

    Returns
    -------
    table, info
        The table (physical values, -1 below the horizon) and a JSON-able dict with
        ``anisotropy_error``, ``reciprocity_error``, ``below_horizon_bins``,
        ``eval_seconds``, ``sampling``, ``source``, ``phi_d_bins`` and ``variant``.

    Raises
    ------
    ValueError
        The dict does not build, or the BSDF is anisotropic beyond the tolerance.
    """
    evaluate = mitsuba_evaluator(bsdf)
    from materials.backend import active_variant

    table, info = _tabulate(
        evaluate,
        phi_d_bins,
        allow_anisotropic=allow_anisotropic,
        anisotropy_tol=anisotropy_tol,
        source="Mitsuba",
    )
    info["variant"] = active_variant()
    return table, info


def tabulate_analytic(
    source: Any,
    *,
    phi_d_bins: int = 180,
    allow_anisotropic: bool = False,
    anisotropy_tol: float = ANISOTROPY_TOL,
) -> tuple[MerlTable, dict[str, Any]]:
    """Tabulate an analytic source (an object with ``eval`` or a callable ``(wi, wo)``).

    Same sampling, horizon marking and checks as :func:`tabulate_mitsuba`, in float64 numpy.
    """
    if hasattr(source, "eval"):
        evaluate, name = source.eval, type(source).__name__
    else:
        evaluate, name = source, getattr(source, "__name__", "callable")

    def chunked(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        # Bounded memory: numpy sources allocate several temporaries per row.
        out = np.empty((len(wi), 3))
        for start in range(0, len(wi), _ANALYTIC_CHUNK):
            rows = slice(start, start + _ANALYTIC_CHUNK)
            out[rows] = evaluate(wi[rows], wo[rows])
        return out

    return _tabulate(
        chunked,
        phi_d_bins,
        allow_anisotropic=allow_anisotropic,
        anisotropy_tol=anisotropy_tol,
        source=name,
    )


def mitsuba_conductor_ior(material: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """RGB ``(eta, k)`` that Mitsuba assigns to ``roughconductor`` with ``material=...``.

    The source of :data:`materials.microfacet.NAMED_CONDUCTORS`; regenerate an entry with
    ``.venv/bin/python -c "from materials.tabulate import mitsuba_conductor_ior as f;
    print(f('Au'))"``.
    """
    from materials.backend import load_mitsuba

    mi = load_mitsuba()
    params = mi.traverse(mi.load_dict({"type": "roughconductor", "material": material}))
    eta = np.broadcast_to(np.asarray(params["eta.value"], dtype=np.float32).ravel(), (3,))
    k = np.broadcast_to(np.asarray(params["k.value"], dtype=np.float32).ravel(), (3,))
    return tuple(float(x) for x in eta), tuple(float(x) for x in k)
