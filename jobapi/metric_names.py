"""Metric names: one unit per column.

A result row's ``metric`` (:mod:`jobapi.rows`) is a column of every table and chart made of
rows (``matforge results --pivot``, a batch's methods table, the dashboard's ``metric.``
columns, ``report.pareto``'s panels). Two values share a column only when they are the same
quantity in the same units, so a quality metric that is measured in more than one space
names its space:

=========  ===========================================================================
space      metrics
=========  ===========================================================================
``brdf.``  BRDF values f(wi, wo) in 1/sr at fixed-seed direction pairs (``score`` of MERL
           tables and models, ``train.brdf``): ``brdf.smape`` (Eq. 6 of the hybrid-BRDF
           paper), ``brdf.smape_floor``, ``brdf.mae`` (1/sr), and the analytic part's
           ``brdf.smape_analytic``, ``brdf.smape_floor_analytic``, ``brdf.mae_analytic``
``image.`` pixels of a rendered image against a reference image (``score`` of images,
           ``select`` in scene mode, ``evaluate.tss``): ``image.flip``, ``image.psnr``
           (dB), ``image.ssim``, ``image.mae``, ``image.mse`` (linear RGB for EXR,
           sRGB-encoded [0, 1] for PNG), and ``evaluate.tss``'s per-frame
           ``image.flip_mean``, ``image.flip_max``, ``image.psnr_mean``, ``image.psnr_min``
=========  ===========================================================================

Metrics measured in one space only keep their names: a BTF's ``l1``, ``l1_train``,
``l1_heldout``, ``relative_l1`` (BTF texels, 1/sr), a fabric network's ``loss``,
``rgb.rel``, ``rgb.mse``, ... (held-out queries), and costs and timings (``render_seconds``,
``fused_kernel_ns``, ``bytes``, ...).

The bare names rows had before (:data:`ALIASES`: ``smape``, ``flip``, ``psnr``, ...) are
still accepted wherever a metric is named (``--metric``, ``metric.<name>`` columns and
filters, ``report.pareto``'s ``metrics`` and claims, ``select``'s ``metric``): each stands
for its space's name. ``mae`` was both a BRDF-space and an image MAE: as a row filter it
keeps both; as one column (``metric.mae``) it is refused, naming ``brdf.mae`` and
``image.mae``.

A kind declares the metric names of its rows (:attr:`jobapi.kinds.Kind.metrics`, ``fnmatch``
patterns allowed); a name no kind declares, and no alias, is refused with the closest known
names (:func:`unknown_metric`).
"""

from __future__ import annotations

import difflib
import fnmatch
from collections.abc import Iterable, Sequence

#: The spaces of :data:`SPACED` metrics, with what their values are.
SPACES = {
    "brdf": "BRDF values f(wi, wo) in 1/sr at fixed-seed direction pairs",
    "image": "pixels of a rendered image against a reference image",
}
#: The quality metrics of each space, as named in the space's own documents (``metrics.json``
#: keys, a score's ``metrics`` param): the row name is ``<space>.<name>``.
SPACED: dict[str, tuple[str, ...]] = {
    "brdf": (
        "smape", "smape_floor", "mae", "smape_analytic", "smape_floor_analytic", "mae_analytic"
    ),
    "image": (
        "flip", "psnr", "ssim", "mae", "mse", "flip_mean", "flip_max", "psnr_mean", "psnr_min"
    ),
}  # fmt: skip


def qualified(space: str, name: str) -> str:
    """The row name of metric ``name`` measured in ``space`` (``"brdf"``, ``"image"``):
    ``"brdf.mae"``; a name that is already qualified, or not a quality metric of that space,
    is returned as it is."""
    if space not in SPACED:
        raise ValueError(f"unknown metric space {space!r}; one of {', '.join(SPACED)}")
    return f"{space}.{name}" if name in SPACED[space] else name


#: Old (bare) names and the qualified names they stand for.
ALIASES: dict[str, tuple[str, ...]] = {}
for _space, _names in SPACED.items():
    for _name in _names:
        ALIASES.setdefault(_name, ())
        ALIASES[_name] += (f"{_space}.{_name}",)
del _space, _names, _name


def resolve(name: str) -> tuple[str, ...]:
    """The row names ``name`` stands for: its qualified names if it is an alias (``"mae"``:
    ``("brdf.mae", "image.mae")``), else itself."""
    return ALIASES.get(name, (name,))


def matches(row_metric: str, asked: str | Iterable[str]) -> bool:
    """Whether a row's metric is one of those ``asked`` (names or aliases; a row of a kind
    that still writes an old name, ``smape``, is the metric it stands for)."""
    names = (asked,) if isinstance(asked, str) else asked
    mine = {row_metric, *resolve(row_metric)}
    return any(n == row_metric or mine & set(resolve(n)) for n in names)


def one_column(name: str) -> str | None:
    """The one row name of a column called ``name``; ``None`` when ``name`` is an alias of
    metrics in two spaces (``mae``), which one column cannot hold."""
    got = resolve(name)
    return got[0] if len(got) == 1 else None


def declared(patterns: Iterable[str], name: str) -> bool:
    """Whether ``name`` is one of ``patterns`` (names or ``fnmatch`` patterns)."""
    return any(p == name or fnmatch.fnmatchcase(name, p) for p in patterns)


def unknown_metric(
    name: str, known: Sequence[str], *, column: bool = False, prefix: str = ""
) -> str | None:
    """Why ``name`` is not a metric (the closest of ``known``, names or patterns, and of
    the aliases suggested, each written after ``prefix``, e.g. ``"metric."``), or ``None``
    when it is one. With ``column``, an alias of two spaces' metrics is refused too (one
    column, one unit)."""
    if name in ALIASES:
        if column and one_column(name) is None:
            return (
                f"{prefix}{name} is measured in {len(resolve(name))} spaces, which one column "
                f"cannot mix: use {' or '.join(repr(prefix + n) for n in resolve(name))}"
            )
        return None
    if declared(known, name):
        return None
    plain = sorted({k for k in known if not any(c in k for c in "*?[")} | set(ALIASES))
    # a known name with a suffix or prefix first ("smape_mean": smape), longest first,
    # then the names spelt alike
    within = sorted(
        (k for k in plain if len(k) >= 3 and k != name and (k in name or name in k)),
        key=lambda k: (-len(k) if k in name else len(k), k),
    )
    close: list[str] = []
    for cand in [*within, *difflib.get_close_matches(name, plain, n=3, cutoff=0.6)]:
        for full in resolve(cand):
            if full not in close:
                close.append(full)
    hint = f"; did you mean {' or '.join(repr(prefix + c) for c in close[:3])}?" if close else ""
    return f"unknown metric {name!r}{hint} (each kind's metrics: docs/reference/kinds.md)"
