"""A Mitsuba 3 BSDF that renders MERL tables: interpolated lookup, fitted-lobe sampling.

The plugin (registered as ``"merl_table"`` by :func:`register_merl_bsdf`) is a Python
``mi.BSDF``; in Mitsuba's vectorised RGB variants it is traced into the render kernel. It
needs one (``llvm_ad_rgb`` or ``cuda_ad_rgb``, as ``MATFORGE_VARIANT`` says): it uses only
the variant's own types (``mi.Float``, ``mi.TensorXf``, ``dr.gather``), no backend module
(``tests/unit/evaluators/render/test_variant_generic.py`` guards both), and
``scripts/gpu_check.sh`` renders it on ``cuda_ad_rgb`` on a GPU machine. Under the
``scalar_rgb`` fallback, registration raises ``RuntimeError``. On 2 cores, with the
float32 table, it renders at about 0.7x the speed of the native BSDF it tabulates
(``benchmarks/bench_merl_bsdf.py``; BENCHMARKS.md): the gap is the table's random reads
(17.5 MB, larger than a core's L2), not arithmetic. Smaller tables are read faster: the
``precision`` parameter holds the table as ``float16`` (one 64-bit word of three IEEE
halves per bin, 11.7 MB) or ``rgb9e5`` (one 32-bit word per bin, three 9-bit mantissas
sharing a 5-bit exponent, 5.8 MB); rgb9e5 measured 0.81-0.91x native against 0.68-0.74x
for float32 (CPU time, three runs, an Intel Xeon with 2 MB of L2 per core). The default
stays ``float32``, so renders keep their bytes.

Evaluation
    The multilinear interpolation of :func:`materials.halfdiff.lookup` (``interpolate=True``)
    in Dr.Jit: the Rusinkiewicz angles of :func:`~materials.halfdiff.halfdiff_angles` (the
    trigonometry-free twin of :func:`~materials.halfdiff.halfdiff_components`: three
    ``atan2`` and no ``sin``/``cos``), the MERL bin coordinates of
    :func:`~materials.halfdiff.merl_coordinates` (both called with
    :func:`~materials.halfdiff.drjit_ops`), eight ``dr.gather`` calls of one RGB bin each,
    theta_h and theta_d clamped at the table edges, phi_d periodic. The table is held as
    float32 (17.5 MB for 180 phi_d bins) unless ``precision`` says otherwise.
Storage
    ``precision``: ``float32`` (default, exact), ``float16`` (relative rounding at most
    2^-11 per channel; decoded with integer shifts and one multiply, no 16-bit gathers, which
    LLVM splits into scalar loads) or ``rgb9e5`` (the largest channel of a bin within 2^-9,
    the others within half a unit of the shared scale; only for tables whose bins are
    missing in all channels or none, a missing bin being the word ``0xFFFFFFFF``). The
    encodings round the float32 table. ``layout``: ``phi_d`` (default, MERL's order) or
    ``theta_h`` (theta_h fastest); same values, other addresses.
Missing entries
    Negative entries are missing (MERL's convention). As in the numpy reference, a missing
    corner gets zero weight and the other corners are renormalised, per channel; where all
    eight corners of a channel are missing the BSDF returns **0** there (the numpy
    reference returns ``MISSING``), so a renderer never sees a negative value. When every
    bin is missing in all its channels or in none (as in matforge's tabulations), the
    lookup tests one channel per corner and keeps one weight sum; the result is the same.
Frame and sides
    Directions in the local shading frame, z up; ``cos theta_i = si.wi.z``. One-sided: 0 (and
    pdf 0) when ``wi.z <= 0`` or ``wo.z <= 0``. Flags: glossy reflection, front side.
Importance sampling
    A one-sample mixture (the balance heuristic of multiple importance sampling) of
    visible-normal GGX sampling (Heitz 2018, through Mitsuba's own
    ``mi.MicrofacetDistribution``) and cosine-hemisphere sampling, as in Sec. 5.2 of
    De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering":
    "MIS between cosine sampling and GGX lobe sampling". The lobe's ``alpha`` and the
    mixture weight come from :func:`fit_sampling_lobe`, a least-squares fit of
    ``k_d + k_s D G1^2 / (4 cos^2 theta_h)`` to the table near the specular configuration.
    ``pdf`` is the exact mixture density of what ``sample`` draws, 0 below the horizon.
"""

from __future__ import annotations

import types
from typing import Any

import numpy as np

from evaluators.render.bsdfs.common import MixtureReflector, MixtureSampling
from evaluators.render.plugins import register_vectorised_bsdf
from materials import halfdiff as hd
from materials.lobe_fit import SamplingLobe, fit_sampling_lobe
from storage.formats.merl import MerlTable, read_merl

#: The plugin name under which :func:`register_merl_bsdf` registers the BSDF.
MERL_BSDF_NAME = "merl_table"


def register_merl_bsdf(mi: types.ModuleType) -> type:
    """Define and register the ``"merl_table"`` BSDF for Mitsuba's current variant.

    ``mi`` is the module returned by :func:`materials.backend.load_mitsuba`.
    Idempotent per variant; returns the class. Needs a vectorised RGB variant
    (``llvm_ad_rgb``, ``cuda_ad_rgb``); raises ``RuntimeError`` otherwise.
    """
    return register_vectorised_bsdf(mi, MERL_BSDF_NAME, MerlBSDF, "MERL table BSDF")


#: Storage precisions of the table: ``float32`` (exact, 17.5 MB at 180 phi_d bins) and
#: ``float16`` (IEEE half, 8.7 MB; relative rounding at most 2^-11).
PRECISIONS = ("float32", "float16", "rgb9e5")
#: Orders of the table in memory: ``phi_d`` fastest (MERL's own) or ``theta_h`` fastest.
LAYOUTS = ("phi_d", "theta_h")


#: The word of a missing bin in the ``rgb9e5`` table (decodes as -1 in every channel).
RGB9E5_MISSING = 0xFFFFFFFF


def encode_rgb9e5(rgb: np.ndarray) -> np.ndarray:
    """``(n, 3)`` non-negative RGB (negative: a missing bin) to ``uint32`` shared-exponent
    words: three 9-bit mantissas and a 5-bit exponent (bias 15), rounded to nearest, as in
    OpenGL's ``EXT_texture_shared_exponent``; values clamped to 65408, the format's largest.
    The largest channel keeps 9 significant bits (relative error at most 2^-9: its mantissa
    is at least 256); smaller channels share its scale (error at most half a unit of it)."""
    n_bits, bias = 9, 15
    top = (2**n_bits - 1) / 2**n_bits * 2.0 ** (31 - bias)
    x = np.clip(np.asarray(rgb, np.float64), 0.0, top)
    peak = x.max(axis=1)
    with np.errstate(divide="ignore"):
        exp = np.maximum(-bias - 1, np.floor(np.log2(np.maximum(peak, 1e-300)))) + 1 + bias
    mant_peak = np.floor(peak / 2.0 ** (exp - bias - n_bits) + 0.5)
    exp = np.where(mant_peak >= 2**n_bits, exp + 1, exp)
    mant = np.floor(x / 2.0 ** (exp - bias - n_bits)[:, None] + 0.5).astype(np.uint32)
    words = mant[:, 0] | (mant[:, 1] << 9) | (mant[:, 2] << 18) | (exp.astype(np.uint32) << 27)
    return np.where((np.asarray(rgb) < 0).any(axis=1), np.uint32(RGB9E5_MISSING), words)


def whole_bins_missing(rgb: np.ndarray) -> bool:
    """True when every bin of ``rgb`` is missing (negative) in all its channels or in none."""
    valid = np.asarray(rgb) >= 0.0
    return bool(np.array_equal(valid.all(axis=-1), valid.any(axis=-1)))


def check_storage(rgb: np.ndarray, precision: str, layout: str) -> None:
    """Raise ``ValueError`` naming the problem when ``rgb`` cannot be held as asked."""
    if precision not in PRECISIONS:
        raise ValueError(f"merl_table: precision must be one of {PRECISIONS}, not {precision!r}")
    if layout not in LAYOUTS:
        raise ValueError(f"merl_table: layout must be one of {LAYOUTS}, not {layout!r}")
    if precision == "rgb9e5" and not whole_bins_missing(rgb):
        raise ValueError(
            "merl_table: precision 'rgb9e5' needs bins missing in all channels "
            "or none; this table has bins missing in some channels only"
        )


def merl_bsdf(
    mi: types.ModuleType,
    table: MerlTable,
    lobe: SamplingLobe | None = None,
    *,
    precision: str = "float32",
    layout: str = "phi_d",
) -> Any:
    """An instantiated table BSDF (``mi.BSDF``) for ``table``; fits the lobe if not given.

    ``precision`` and ``layout`` choose how the table is held in memory (:data:`PRECISIONS`,
    :data:`LAYOUTS`); the defaults are the exact float32 table in MERL's order.
    """
    data = table.rgb.astype(np.float32)
    check_storage(data, precision, layout)  # plain ValueErrors, before Mitsuba wraps them
    register_merl_bsdf(mi)
    lobe = lobe or fit_sampling_lobe(table.rgb)
    return mi.load_dict(
        {
            "type": MERL_BSDF_NAME,
            "data": mi.TensorXf(data),
            "alpha": lobe.alpha,
            "specular_weight": lobe.specular_weight,
            "precision": precision,
            "layout": layout,
        }
    )


class MerlBSDF(MixtureReflector):
    """MERL table BSDF (plugin ``"merl_table"``).

    =====================  =============  ========  =========================================
    parameter              type           default   meaning
    =====================  =============  ========  =========================================
    ``filename``           string         --        a MERL ``.binary`` file, read and
                                                    validated by
                                                    :func:`storage.formats.merl.read_merl`
    ``data``               ``TensorXf``   --        the table itself, ``(90, 90, P, 3)``
                                                    physical BRDF in 1/sr (instead of a file)
    ``alpha``              float          fitted    GGX roughness of the sampling lobe
    ``specular_weight``    float          fitted    probability of sampling the GGX lobe
    ``precision``          string         float32   ``float32``, ``float16`` or ``rgb9e5``:
                                                    how the table is held (module docs)
    ``layout``             string         phi_d     ``phi_d`` or ``theta_h``: which
                                                    angle's bins are adjacent in memory
    =====================  =============  ========  =========================================

    Example (XML, as the chi-square harness loads it)::

        <bsdf type="merl_table"><string name="filename" value="gold.binary"/></bsdf>
    """

    def __init__(self, props: Any) -> None:
        MixtureReflector.__init__(self, props)
        mi, dr = self.mi, self.dr
        flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
        filename = props.get("filename", None)
        data = props.get("data", None)
        if (filename is None) == (data is None):
            raise ValueError("merl_table: give exactly one of 'filename' and 'data'")
        if filename is not None:
            rgb = read_merl(str(filename)).rgb
        else:
            rgb = np.asarray(data.numpy(), dtype=np.float64)
        if rgb.ndim != 4 or rgb.shape[:2] != (90, 90) or rgb.shape[3] != 3:
            raise ValueError(f"merl_table: table shape must be (90, 90, P, 3), got {rgb.shape}")
        self.phi_d_bins = int(rgb.shape[2])
        if self.phi_d_bins not in hd.PHI_D_VARIANTS:
            raise ValueError(f"merl_table: phi_d bins must be 180 or 360, not {rgb.shape[2]}")
        alpha, weight = props.get("alpha", None), props.get("specular_weight", None)
        if alpha is None or weight is None:
            lobe = fit_sampling_lobe(rgb)
            alpha = lobe.alpha if alpha is None else alpha
            weight = lobe.specular_weight if weight is None else weight
        if not (alpha > 0.0 and 0.0 <= weight <= 1.0):
            raise ValueError("merl_table: need alpha > 0, 0 <= specular_weight <= 1")
        self.alpha, self.specular_weight = float(alpha), float(weight)
        self.sampling = MixtureSampling(self.alpha, self.specular_weight)
        precision = str(props.get("precision", "float32"))
        layout = str(props.get("layout", "phi_d"))
        table = np.asarray(rgb, dtype=np.float32)
        # Unknown names, and rgb9e5 with bins missing in some channels, are refused.
        check_storage(table, precision, layout)
        self.precision, self.layout = precision, layout
        # True when every bin is missing in all its channels or in none (tabulations):
        # the lookup then tests one channel and keeps one weight sum.
        self.whole_bins_missing = whole_bins_missing(table)
        if layout == "theta_h":
            table = table.transpose(2, 1, 0, 3)  # (P, 90 theta_d, 90 theta_h, 3)
        table = np.ascontiguousarray(table).ravel()
        if precision == "float16":
            # One 64-bit word per bin: R, G, B as IEEE halves in bits 0-15, 16-31, 32-47.
            half = table.astype(np.float16).view(np.uint16).reshape(-1, 3).astype(np.uint64)
            words = half[:, 0] | (half[:, 1] << 16) | (half[:, 2] << 32)
            uint64: Any = dr.uint64_array_t(mi.Float)
            self.table = uint64(words)
        elif precision == "rgb9e5":
            self.table = mi.UInt32(encode_rgb9e5(table.reshape(-1, 3)))
        else:
            self.table = mi.Float(table)
        self.m_flags = flags
        self.m_components = [flags]

    # -- the table --------------------------------------------------------------------
    def brdf(self, ctx: Any, wi: Any, wo: Any, active: Any = True) -> Any:
        """Interpolated BRDF (1/sr, ``mi.Color3f``), no cosine; 0 below the horizon
        (``ctx`` is not used)."""
        mi, dr = self.mi, self.dr
        ops = hd.drjit_ops(dr)
        active = active & (wi.z > 0) & (wo.z > 0)
        theta_h, theta_d, phi_d = hd.halfdiff_angles(wi.x, wi.y, wi.z, wo.x, wo.y, wo.z, ops)
        n_p = self.phi_d_bins
        u_h, u_d, u_p = hd.merl_coordinates(theta_h, theta_d, phi_d, n_p, ops)
        ax_h = self._corners(u_h, hd.RES_THETA_H, False)
        ax_d = self._corners(u_d, hd.RES_THETA_D, False)
        ax_p = self._corners(u_p, n_p, True)
        acc = dr.zeros(mi.Color3f)
        # Per-bin missing entries: one weight sum; per-channel ones: one per channel.
        wsum = dr.zeros(mi.Float if self.whole_bins_missing else mi.Color3f)
        for i_h, w_h in ax_h:
            for i_d, w_d in ax_d:
                w_hd = w_h * w_d
                for i_p, w_p in ax_p:
                    v = self._read(self._index(i_h, i_d, i_p), active)
                    if self.whole_bins_missing:
                        w = dr.select(v.x >= 0.0, w_hd * w_p, 0.0)
                        acc = dr.fma(v, w, acc)
                    else:
                        ok = v >= 0.0
                        w = dr.select(ok, w_hd * w_p, 0.0)
                        acc += dr.select(ok, w * v, 0.0)
                    wsum += w
        value = dr.select(wsum > 0.0, acc / dr.maximum(wsum, 1e-30), 0.0)
        return dr.select(active, value, 0.0)

    def _corners(self, u: Any, n: int, periodic: bool) -> tuple[tuple[Any, Any], tuple[Any, Any]]:
        """The two bins (``mi.UInt32``) and weights of MERL coordinate ``u`` on an axis of
        ``n`` bins, clamped at the edges or ``periodic``."""
        mi, dr = self.mi, self.dr
        # As halfdiff._interpolate: bin centres sit at integer p = u - 1/2.
        p = u - 0.5
        lower = dr.floor(p)
        w1 = p - lower
        i0 = mi.Int32(lower)
        i1 = i0 + 1
        if periodic:
            i0 = dr.select(i0 < 0, i0 + n, i0)
            i1 = dr.select(i1 >= n, i1 - n, i1)
        # Clamping also keeps every gather in bounds, whatever the input.
        i0 = mi.UInt32(dr.clip(i0, 0, n - 1))
        i1 = mi.UInt32(dr.clip(i1, 0, n - 1))
        return (i0, 1.0 - w1), (i1, w1)

    def _half(self, bits: Any) -> Any:
        """IEEE half (low 16 bits of ``mi.UInt32``) to ``mi.Float``."""
        # The magnitude's bits shifted into float32's place and scaled by 2^(127 - 15)
        # (exact for normals, subnormals and zero), sign copied. Halves hold no infinities
        # or NaNs here (the table is finite).
        magnitude: Any = self.dr.reinterpret_array(
            self.mi.Float, ((bits & 0x7FFF) << 13) | ((bits & 0x8000) << 16)
        )
        return magnitude * 5.192296858534828e33

    def _index(self, i_h: Any, i_d: Any, i_p: Any) -> Any:
        if self.layout == "theta_h":
            return (i_p * hd.RES_THETA_D + i_d) * hd.RES_THETA_H + i_h
        return (i_h * hd.RES_THETA_D + i_d) * self.phi_d_bins + i_p

    def _read(self, index: Any, active: Any) -> Any:
        mi, dr = self.mi, self.dr
        if self.precision == "float32":
            return dr.gather(mi.Color3f, self.table, index, active)
        word = dr.gather(type(self.table), self.table, index, active)
        if self.precision == "rgb9e5":
            scale = dr.reinterpret_array(mi.Float, ((word >> 27) + (127 - 15 - 9)) << 23)
            rgb = mi.Color3f(
                mi.Float(word & 0x1FF),
                mi.Float((word >> 9) & 0x1FF),
                mi.Float((word >> 18) & 0x1FF),
            )
            return dr.select(word == RGB9E5_MISSING, -1.0, rgb * scale)
        lo, hi = mi.UInt32(word & 0xFFFFFFFF), mi.UInt32(word >> 32)
        return mi.Color3f(self._half(lo & 0xFFFF), self._half(lo >> 16), self._half(hi & 0xFFFF))

    def to_string(self) -> str:
        return (
            f"MerlBSDF[phi_d_bins={self.phi_d_bins}, alpha={self.alpha:.4g}, "
            f"specular_weight={self.specular_weight:.3g}]"
        )
