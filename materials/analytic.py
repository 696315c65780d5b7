"""Analytic BRDF sources of known ground truth, for MERL tables and tests.

Each source is a small frozen dataclass with ``eval(wi, wo) -> (N, 3)``: the plain BRDF in
1/sr (no cosine), linear RGB, for ``(N, 3)`` unit directions in the local frame (z up); 0
where either direction is at or below the horizon. Parameters are validated on
construction (``ValueError``). :data:`ANALYTIC_MODELS` maps the names used in job specs
(``{"analytic": {"model": "ggx", ...}}``) to the classes; :func:`build_analytic` builds one
from such a mapping.

Where Mitsuba 3 has the same model, ``mitsuba_dict()`` returns the equivalent plugin dict
(``None`` otherwise); the tests compare the two evaluations.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import numpy as np

from materials import microfacet as mf
from materials.thinfilm import iridescence_fresnel

RGB = tuple[float, float, float]


class AnalyticBRDF(Protocol):
    """What tabulation needs from a source."""

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``(N, 3)`` plain BRDF (1/sr) at ``(N, 3)`` direction pairs."""
        ...


def _rgb(name: str, value: Any, *, lo: float = 0.0, hi: float = np.inf) -> RGB:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
    if not np.all(np.isfinite(arr)) or np.any(arr < lo) or np.any(arr > hi):
        raise ValueError(f"{name} must be 3 finite values in [{lo}, {hi}], got {value!r}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _alpha(value: float) -> float:
    if not np.isfinite(value) or not 0.0 < value <= 4.0:
        raise ValueError(f"alpha must be in (0, 4], got {value!r}")
    return float(value)


def _above(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    return (np.asarray(wi)[:, 2] > 0) & (np.asarray(wo)[:, 2] > 0)


@dataclass(frozen=True)
class Lambert:
    """Ideal diffuse reflector: ``f = albedo / pi`` (Mitsuba ``diffuse``).

    Parameters
    ----------
    albedo
        RGB hemispherical reflectance in ``[0, 1]``.
    """

    albedo: RGB = (0.5, 0.5, 0.5)

    def __post_init__(self) -> None:
        object.__setattr__(self, "albedo", _rgb("albedo", self.albedo, hi=1.0))

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        return _above(wi, wo)[:, None] * (np.asarray(self.albedo) / np.pi)

    def mitsuba_dict(self) -> dict[str, Any] | None:
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(self.albedo)}}


@dataclass(frozen=True)
class _Conductor:
    """Shared part of the rough conductors: ``D G2 F_conductor / (4 cos_i cos_o)``."""

    distribution: ClassVar[mf.Distribution]
    alpha: float = 0.1
    eta: RGB | None = None
    k: RGB | None = None
    material: str | None = None
    shadowing: mf.Shadowing = "separable"

    def __post_init__(self) -> None:
        object.__setattr__(self, "alpha", _alpha(self.alpha))
        if self.material is not None:
            if self.eta is not None or self.k is not None:
                raise ValueError("give either material or eta and k, not both")
            eta, k = mf.named_conductor(self.material)
        elif self.eta is None or self.k is None:
            raise ValueError("give a named material or both eta and k (RGB)")
        else:
            eta, k = np.asarray(self.eta), np.asarray(self.k)
        object.__setattr__(self, "eta", _rgb("eta", eta))
        object.__setattr__(self, "k", _rgb("k", k))
        if self.shadowing not in ("separable", "height_correlated"):
            raise ValueError(
                f"shadowing must be 'separable' or 'height_correlated', got {self.shadowing!r}"
            )

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        eta, k = np.asarray(self.eta), np.asarray(self.k)
        return mf.specular_brdf(
            wi,
            wo,
            self.alpha,
            lambda c: mf.fresnel_conductor(c, eta, k),
            distribution=self.distribution,
            shadowing=self.shadowing,
        )

    def mitsuba_dict(self) -> dict[str, Any] | None:
        if self.shadowing != "separable":
            return None  # Mitsuba's roughconductor uses separable Smith shadowing only
        return {
            "type": "roughconductor",
            "distribution": self.distribution,
            "alpha": self.alpha,
            "eta": {"type": "rgb", "value": list(self.eta or ())},
            "k": {"type": "rgb", "value": list(self.k or ())},
        }


@dataclass(frozen=True)
class GGXConductor(_Conductor):
    """Rough conductor with the GGX NDF and complex IOR ``eta + i k`` per RGB channel.

    Parameters
    ----------
    alpha
        GGX roughness in ``(0, 4]``.
    eta, k
        RGB complex IOR; or ``material``, a Mitsuba conductor name (e.g. ``"Au"``).
    shadowing
        ``"separable"`` (Mitsuba's ``roughconductor``) or ``"height_correlated"``.
    """

    distribution: ClassVar[mf.Distribution] = "ggx"


@dataclass(frozen=True)
class BeckmannConductor(_Conductor):
    """Rough conductor with the Beckmann NDF; parameters as :class:`GGXConductor`."""

    distribution: ClassVar[mf.Distribution] = "beckmann"


@dataclass(frozen=True)
class Plastic:
    """Dielectric-coated diffuse base, the model of Mitsuba 3's ``roughplastic``.

    ``f = F(dot(wi, h); eta) D G2 / (4 cos_i cos_o)
    + rho / (pi eta^2) T(cos_i) T(cos_o) / (1 - R_int)``
    (Weidlich and Wilkie 2007, "Arbitrarily Layered Micro-Facet Surfaces"; Jakob's
    ``roughplastic``): a rough dielectric specular lobe over a Lambertian base seen through
    the interface. ``T`` is the rough interface's directional transmittance
    (:func:`materials.microfacet.specular_transmittance`), ``R_int`` the base-side
    hemispherical reflectance of the interface, ``2 int E(mu; 1/eta) mu dmu``, which
    accounts for light bouncing inside the coating (``rho R_int`` with ``nonlinear=True``).
    To coincide with Mitsuba, ``T`` is tabulated at 64 cosines ``max(i/63, 1e-6)`` and
    interpolated linearly, and ``R_int`` is the 64-node average; only the quadrature of the
    two integrals differs (ours: Gauss-Legendre over NDF-distributed normals).

    Parameters
    ----------
    alpha
        Roughness of the coating interface, ``(0, 4]``.
    diffuse
        RGB albedo of the base, ``[0, 1]``.
    eta
        Relative IOR of the coating (interior over exterior), ``> 1``; Mitsuba's default is
        polypropylene in air, ``1.49 / 1.000277``.
    distribution
        ``"ggx"`` or ``"beckmann"``.
    nonlinear
        Account for the colour shift of internal scattering (Mitsuba's ``nonlinear``).
    """

    alpha: float = 0.1
    diffuse: RGB = (0.5, 0.5, 0.5)
    eta: float = 1.49 / 1.000277
    distribution: mf.Distribution = "ggx"
    nonlinear: bool = False
    _tables: tuple[np.ndarray, float] = field(init=False, repr=False, compare=False)

    RES: ClassVar[int] = 64

    def __post_init__(self) -> None:
        object.__setattr__(self, "alpha", _alpha(self.alpha))
        object.__setattr__(self, "diffuse", _rgb("diffuse", self.diffuse, hi=1.0))
        if not np.isfinite(self.eta) or self.eta <= 1.0 or self.eta > 4.0:
            raise ValueError(f"eta must be in (1, 4], got {self.eta!r}")
        if self.distribution not in ("ggx", "beckmann"):
            raise ValueError(f"distribution must be 'ggx' or 'beckmann', got {self.distribution!r}")
        mu = np.maximum(np.linspace(0.0, 1.0, self.RES), 1e-6)
        trans = mf.specular_transmittance(mu, self.alpha, self.eta, distribution=self.distribution)
        internal = mf.specular_albedo(
            mu,
            self.alpha,
            lambda c: mf.fresnel_dielectric(c, 1.0 / self.eta),
            distribution=self.distribution,
        )
        object.__setattr__(self, "_tables", (trans, float(2.0 * np.mean(internal * mu))))

    def _transmittance(self, cos_t: np.ndarray) -> np.ndarray:
        # Mitsuba's lerp_gather: x = cos (res - 1), index = min(int(x), res - 2).
        table = self._tables[0]
        x = np.clip(cos_t, 0.0, 1.0) * (self.RES - 1)
        idx = np.minimum(x.astype(np.int64), self.RES - 2)
        return table[idx] + (table[idx + 1] - table[idx]) * (x - idx)

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        spec = mf.specular_brdf(
            wi,
            wo,
            self.alpha,
            lambda c: mf.fresnel_dielectric(c, self.eta),
            distribution=self.distribution,
        )
        rho = np.asarray(self.diffuse)
        r_int = self._tables[1]
        rho_eff = rho / (1.0 - (rho * r_int if self.nonlinear else r_int))
        t = self._transmittance(wi[:, 2]) * self._transmittance(wo[:, 2])
        diff = (_above(wi, wo) * t / (np.pi * self.eta**2))[:, None] * rho_eff
        return spec + diff

    def mitsuba_dict(self) -> dict[str, Any] | None:
        return {
            "type": "roughplastic",
            "distribution": self.distribution,
            "alpha": self.alpha,
            "int_ior": self.eta,
            "ext_ior": 1.0,
            "nonlinear": self.nonlinear,
            "diffuse_reflectance": {"type": "rgb", "value": list(self.diffuse)},
        }


#: Samples of the thin-film Fresnel over cos_d in [0, 1] (see :meth:`ThinFilmGGX.fresnel`).
FRESNEL_GRID = 4096


@dataclass(frozen=True)
class ThinFilmGGX:
    """GGX conductor under a thin dielectric film (Belcour & Barla 2017).

    ``f = D G2 F_film(dot(wi, h)) / (4 cos_i cos_o)`` with separable Smith ``G2`` and the
    RGB Airy-summation Fresnel of :func:`materials.thinfilm.iridescence_fresnel`.

    Parameters
    ----------
    alpha
        GGX roughness, ``(0, 4]``.
    thickness_nm
        Film thickness in nanometres, ``[0, 5000]``; below 30 nm the film fades out.
    film_ior
        Real IOR of the film, ``[1, 4]``; 1 means no film.
    eta, k
        RGB complex IOR of the base conductor; or ``material``, a Mitsuba conductor name.
    """

    alpha: float = 0.1
    thickness_nm: float = 300.0
    film_ior: float = 1.5
    eta: RGB | None = None
    k: RGB | None = None
    material: str | None = None

    def __post_init__(self) -> None:
        base = GGXConductor(alpha=self.alpha, eta=self.eta, k=self.k, material=self.material)
        object.__setattr__(self, "alpha", base.alpha)
        object.__setattr__(self, "eta", base.eta)
        object.__setattr__(self, "k", base.k)
        if not np.isfinite(self.thickness_nm) or not 0.0 <= self.thickness_nm <= 5000.0:
            raise ValueError(f"thickness_nm must be in [0, 5000], got {self.thickness_nm!r}")
        if not np.isfinite(self.film_ior) or not 1.0 <= self.film_ior <= 4.0:
            raise ValueError(f"film_ior must be in [1, 4], got {self.film_ior!r}")

    def fresnel_exact(self, cos_d: np.ndarray) -> np.ndarray:
        """RGB film Fresnel reflectance at ``cos_d = dot(wi, h)`` by the full spectral
        Airy summation; shape ``cos_d.shape + (3,)``."""
        return iridescence_fresnel(
            cos_d, self.thickness_nm, self.film_ior, np.asarray(self.eta), np.asarray(self.k)
        )

    def fresnel(self, cos_d: np.ndarray) -> np.ndarray:
        """RGB film Fresnel reflectance at ``cos_d``, interpolated from :meth:`fresnel_exact`
        on a uniform grid of ``FRESNEL_GRID`` cosines in [0, 1], built once per material.

        The film Fresnel depends on ``cos_d`` alone, so a table evaluates the costly spectral
        sum 4k times instead of once per direction pair (a MERL table: 1.5 M pairs, 3 s ->
        0.3 s). Linear interpolation error is below 1e-4 (tested)."""
        grid = self.__dict__.get("_fresnel_grid")
        if grid is None:
            grid = self.fresnel_exact(np.linspace(0.0, 1.0, FRESNEL_GRID))
            object.__setattr__(self, "_fresnel_grid", grid)
        c = np.clip(np.asarray(cos_d, dtype=np.float64), 0.0, 1.0)
        if c.ndim and c.shape[-1] == 1:  # (N, 1) broadcasts against RGB, as in fresnel_exact
            c = c[..., 0]
        x = c * (FRESNEL_GRID - 1)
        i0 = np.minimum(x.astype(np.int64), FRESNEL_GRID - 2)
        t = (x - i0)[..., None]
        return grid[i0] * (1.0 - t) + grid[i0 + 1] * t

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        return mf.specular_brdf(wi, wo, self.alpha, self.fresnel, distribution="ggx")

    def mitsuba_dict(self) -> dict[str, Any] | None:
        return None  # Mitsuba 3 has no thin-film conductor


#: Job-spec model names -> source classes (keyword arguments are the dataclass fields).
ANALYTIC_MODELS: dict[str, type] = {
    "lambert": Lambert,
    "ggx": GGXConductor,
    "beckmann": BeckmannConductor,
    "plastic": Plastic,
    "thin_film_ggx": ThinFilmGGX,
}


def build_analytic(spec: Mapping[str, Any]) -> AnalyticBRDF:
    """Build a source from ``{"model": name, **params}`` (lists become RGB tuples).

    Raises ``ValueError`` naming the model or the parameter that is wrong.
    """
    params = dict(spec)
    name = params.pop("model", None)
    if name not in ANALYTIC_MODELS:
        raise ValueError(
            f"unknown analytic model {name!r}; known: {', '.join(sorted(ANALYTIC_MODELS))}"
        )
    cls = ANALYTIC_MODELS[name]
    known = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(params) - known)
    if unknown:
        raise ValueError(
            f"model {name!r} has no parameter(s) {', '.join(unknown)}; "
            f"known: {', '.join(sorted(known))}"
        )
    params = {key: tuple(v) if isinstance(v, list) else v for key, v in params.items()}
    return cls(**params)
