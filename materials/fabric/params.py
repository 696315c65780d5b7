"""Woven-fabric material parameters (Chen et al. 2024, Table 1) and their sampling ranges.

One :class:`FabricParams` describes a material: a weave pattern, the yarn geometry of Jin et
al. 2022 (twist ``psi``, inclination ``u_max``, height-field scaling ``beta``, the 0.2 gap)
and the shading of Eq. 1-2 (fibre roughness ``alpha``, Lambertian blend ``w``, albedos).
Per-yarn quantities are ``(warp, weft)`` pairs, as in Table 1; a scalar sets both.

The albedos ``kd_*``, ``ks_*`` only enter the recombination of Eq. 8: the four aggregated
components ``C_warp, C_weft, S_warp, S_weft`` are computed with unit albedos.

Sampling ranges (:data:`PARAM_RANGES`). The paper's Table 2 lists the distributions it used,
but its values are missing from our text, so these are our own, chosen to be physically
sensible and documented here; Sec. 5.1 and Fig. 8 only tell us that alpha and beta take
values such as 0.2 ... 0.9 and that psi and u are sampled per pattern:

===========  =====================  ================  =====================================
parameter    allowed                sampled           why
===========  =====================  ================  =====================================
psi_deg      [-80, 80] deg          U(-40, 40)        ply twist angles of real yarns are
                                                      about 15-40 deg, either handedness
u_max_deg    [0, 75] deg            U(10, 45)         Jin et al. fit 16-60 deg; beyond 45
                                                      long satin floats become very tall
alpha        [0.02, 1]              U(0.1, 0.8)       Fig. 8 uses 0.2 ... 0.9; 1 = sphere
beta         [0, 2]                 U(0.1, 1.0)       Fig. 8 uses 0.2 ... 0.9; 0 = flat
w            [0, 1]                 U(0.3, 1.0)       Jin et al. fit w about 0.7
kd, ks       [0, 1] per channel     U(0.05, 0.9)      albedos, only for Eq. 8
gap          [0, 0.9]               fixed 0.2         Sec. 5.1: "The gap size is set as 0.2"
t_rho        (0, 20]                fixed 2           Sec. 3.1: "T rho ... a value of 2"
===========  =====================  ================  =====================================
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np

from materials.fabric.patterns import PATTERNS, Pattern, get_pattern


class YarnPair(NamedTuple):
    """A per-yarn quantity: the warp value and the weft value."""

    warp: float
    weft: float


class ParamRange(NamedTuple):
    """Allowed interval and the interval :func:`sample_params` draws from uniformly."""

    low: float
    high: float
    sample_low: float
    sample_high: float


#: Allowed and sampled ranges per parameter (see the module docstring for the reasons).
PARAM_RANGES: dict[str, ParamRange] = {
    "psi_deg": ParamRange(-80.0, 80.0, -40.0, 40.0),
    "u_max_deg": ParamRange(0.0, 75.0, 10.0, 45.0),
    "alpha": ParamRange(0.02, 1.0, 0.1, 0.8),
    "beta": ParamRange(0.0, 2.0, 0.1, 1.0),
    "w": ParamRange(0.0, 1.0, 0.3, 1.0),
    "albedo": ParamRange(0.0, 1.0, 0.05, 0.9),
    "gap": ParamRange(0.0, 0.9, 0.2, 0.2),
    "t_rho": ParamRange(1e-6, 20.0, 2.0, 2.0),
}

_PAIRS = ("psi_deg", "u_max_deg", "alpha", "beta")
_RGB = ("kd_warp", "kd_weft", "ks_warp", "ks_weft")


def _pair(name: str, value: Any) -> YarnPair:
    if isinstance(value, int | float):
        pair = YarnPair(float(value), float(value))
    else:
        try:
            warp, weft = value
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a number or a (warp, weft) pair") from None
        pair = YarnPair(float(warp), float(weft))
    rng = PARAM_RANGES[name]
    for v in pair:
        if not (math.isfinite(v) and rng.low <= v <= rng.high):
            raise ValueError(f"{name} must lie in [{rng.low}, {rng.high}], got {v}")
    return pair


def _rgb(name: str, value: Any) -> tuple[float, float, float]:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
    if not np.all(np.isfinite(arr)) or np.any(arr < 0) or np.any(arr > 1):
        raise ValueError(f"{name} must be in [0, 1] (a number or RGB), got {value!r}")
    return float(arr[0]), float(arr[1]), float(arr[2])


def _scalar(name: str, value: Any) -> float:
    v = float(value)
    rng = PARAM_RANGES[name]
    if not (math.isfinite(v) and rng.low <= v <= rng.high):
        raise ValueError(f"{name} must lie in [{rng.low}, {rng.high}], got {v}")
    return v


#: Allowed values of :attr:`FabricParams.yarn_profile` (the first is the default).
YARN_PROFILES = ("smooth", "jin")


@dataclass(frozen=True)
class FabricParams:
    """One woven-fabric material (Table 1 of Chen et al. 2024), validated on creation.

    Example: ``FabricParams(get_pattern("twill_3x3"), psi_deg=25, u_max_deg=(20, 30),
    alpha=0.3, beta=0.6)``.
    """

    pattern: Pattern
    """The weave pattern (see ``patterns.py``); a name of a built-in is accepted too."""
    psi_deg: YarnPair = YarnPair(0.0, 0.0)
    """Twist angle psi of the ply fibres about the yarn axis, degrees, (warp, weft)."""
    u_max_deg: YarnPair = YarnPair(20.0, 20.0)
    """Inclination u of the yarn axis at the ends of a float, degrees, (warp, weft)."""
    alpha: YarnPair = YarnPair(0.3, 0.3)
    """Fibre-like microflake roughness, S = diag(1, 1, alpha^2) in the ply frame."""
    beta: YarnPair = YarnPair(1.0, 1.0)
    """Height-field scaling: 0 gives flat yarns, 1 the full curved cylinders."""
    w: float = 0.7
    """Blend weight of the Lambertian term that follows the ply normal (Eq. 1)."""
    kd_warp: tuple[float, float, float] = (0.5, 0.5, 0.5)
    """Diffuse albedo k_d of warp yarns, RGB (Eq. 8 only)."""
    kd_weft: tuple[float, float, float] = (0.5, 0.5, 0.5)
    """Diffuse albedo k_d of weft yarns, RGB (Eq. 8 only)."""
    ks_warp: tuple[float, float, float] = (0.5, 0.5, 0.5)
    """Specular albedo k_s of warp yarns, RGB (Eq. 8 only)."""
    ks_weft: tuple[float, float, float] = (0.5, 0.5, 0.5)
    """Specular albedo k_s of weft yarns, RGB (Eq. 8 only)."""
    gap: float = 0.2
    """Fraction of each cell's width left empty beside the yarn (Sec. 5.1: 0.2)."""
    t_rho: float = 2.0
    """Optical thickness T rho of the SpongeCake layer (Sec. 3.1: always 2)."""
    yarn_profile: str = "smooth"
    """Yarn height profile (:data:`YARN_PROFILES`): ``"smooth"`` tapers the height to zero
    over the outer half of each float (not Jin et al.'s yarn), ``"jin"`` keeps Jin's slopes
    on 90 % of the float and closes the height in a thin band (``materials.fabric.yarn``)."""

    def __post_init__(self) -> None:
        pattern = self.pattern
        if isinstance(pattern, str):
            pattern = get_pattern(pattern, PATTERNS)
        if not isinstance(pattern, Pattern):
            raise ValueError(f"pattern must be a Pattern or a built-in name, got {pattern!r}")
        object.__setattr__(self, "pattern", pattern)
        for name in _PAIRS:
            object.__setattr__(self, name, _pair(name, getattr(self, name)))
        for name in _RGB:
            object.__setattr__(self, name, _rgb(name, getattr(self, name)))
        object.__setattr__(self, "w", _scalar("w", self.w))
        object.__setattr__(self, "gap", _scalar("gap", self.gap))
        object.__setattr__(self, "t_rho", _scalar("t_rho", self.t_rho))
        if self.yarn_profile not in YARN_PROFILES:
            raise ValueError(
                f"yarn_profile must be one of {', '.join(YARN_PROFILES)}, got {self.yarn_profile!r}"
            )

    def replace(self, **changes: Any) -> FabricParams:
        """A copy with some fields changed (validated again)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        unknown = set(changes) - set(values)
        if unknown:
            raise ValueError(f"unknown FabricParams fields {sorted(unknown)}")
        values.update(changes)
        return FabricParams(**values)

    def albedos(self) -> np.ndarray:
        """``(4, 3)`` float64: the RGB albedo multiplying each component of Eq. 8.

        Rows follow :data:`materials.fabric.integrand.COMPONENTS`:
        ``kd_warp, kd_weft, ks_warp, ks_weft``.
        """
        return np.array([self.kd_warp, self.kd_weft, self.ks_warp, self.ks_weft])


def sample_params(rng: np.random.Generator, pattern: Pattern | str) -> FabricParams:
    """Draw a material from :data:`PARAM_RANGES` (warp and weft drawn independently).

    ``gap`` and ``t_rho`` stay at the paper's fixed values.
    """

    def draw(name: str) -> float:
        r = PARAM_RANGES[name]
        return float(rng.uniform(r.sample_low, r.sample_high))

    def rgb() -> tuple[float, float, float]:
        r = PARAM_RANGES["albedo"]
        a = rng.uniform(r.sample_low, r.sample_high, size=3)
        return float(a[0]), float(a[1]), float(a[2])

    return FabricParams(
        pattern=pattern if isinstance(pattern, Pattern) else get_pattern(pattern),
        psi_deg=YarnPair(draw("psi_deg"), draw("psi_deg")),
        u_max_deg=YarnPair(draw("u_max_deg"), draw("u_max_deg")),
        alpha=YarnPair(draw("alpha"), draw("alpha")),
        beta=YarnPair(draw("beta"), draw("beta")),
        w=draw("w"),
        kd_warp=rgb(),
        kd_weft=rgb(),
        ks_warp=rgb(),
        ks_weft=rgb(),
    )


def params_json(params: FabricParams) -> str:
    """The material as the JSON string the plugins' ``params`` property takes
    (``yarn_profile`` only when not the default, so older materials keep their string)."""
    doc: dict[str, Any] = {
        "pattern": params.pattern.name,
        "psi_deg": list(params.psi_deg),
        "u_max_deg": list(params.u_max_deg),
        "alpha": list(params.alpha),
        "beta": list(params.beta),
        "w": params.w,
        "kd_warp": list(params.kd_warp),
        "kd_weft": list(params.kd_weft),
        "ks_warp": list(params.ks_warp),
        "ks_weft": list(params.ks_weft),
        "gap": params.gap,
        "t_rho": params.t_rho,
    }
    if params.yarn_profile != YARN_PROFILES[0]:
        doc["yarn_profile"] = params.yarn_profile
    return json.dumps(doc)
