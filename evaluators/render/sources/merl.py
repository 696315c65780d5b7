"""The ``merl`` material source: ``{"merl": REF}`` renders a MERL table.

``REF`` is an artifact reference (``"sha256:<digest>"`` or ``"job:<id>/<name>"``) to a MERL
``.binary`` file: an upload (``matforge import``) or a table written by another job. Inside
the job the reference is resolved to a verified store path, the file is read and validated
by :mod:`storage.formats.merl`, and the table becomes the ``merl_table`` BSDF of
:mod:`evaluators.render.bsdfs.merl_table` (interpolated lookup, importance sampling with a fitted
GGX lobe).

An optional sibling key ``"table_precision"`` chooses how the table is held in memory while
rendering: ``"float32"`` (the default: the file's values, exact to float32), ``"float16"``
(IEEE halves, one 64-bit word per bin, 11.7 MB) or ``"rgb9e5"`` (one 32-bit word per bin,
three 9-bit mantissas sharing a 5-bit exponent, 5.8 MB; needs bins missing in all channels
or none, as in MERL files and matforge's tabulations). The smaller tables render faster
(fewer cache misses; BENCHMARKS.md) and round the table: relative error at most 2^-11
(float16) or 2^-9 of a bin's largest channel (rgb9e5). Without the key the bytes of a
render are those of the float32 table.

Errors are one line naming the reference: a malformed file fails the job with
``material.merl: <ref>: <what is wrong>``.

This module registers the source when imported; :mod:`evaluators.render.kind` imports it, so the
source exists wherever the ``render`` kind does.
"""

from __future__ import annotations

import types
from typing import TYPE_CHECKING, Any, Literal

from pydantic import Field

from evaluators.render.bsdfs.merl_table import merl_bsdf
from evaluators.render.sources.common import register_material_source
from jobapi.errors import JobFailed
from jobapi.params import Ref, StrictModel
from storage.errors import FormatError
from storage.formats.merl import read_merl

if TYPE_CHECKING:
    from jobapi.context import JobContext


TABLE_PRECISION_DESCRIPTION = (
    "How the table is held while rendering: 'float32' (default, exact), 'float16' (11.7 MB) "
    "or 'rgb9e5' (shared-exponent, 5.8 MB, fastest); the smaller ones round the table."
)


class MerlSiblings(StrictModel):
    """The keys next to ``"merl"`` in a material object."""

    table_precision: Literal["float32", "float16", "rgb9e5"] | None = Field(
        default=None, description=TABLE_PRECISION_DESCRIPTION
    )


def resolve_merl(value: dict[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """Resolve ``{"merl": REF, "table_precision"?: ...}`` to an instantiated ``merl_table``
    BSDF (``mi.BSDF``).

    Raises :class:`JobFailed` when the reference does not resolve, the file is not a valid
    MERL table (or cannot be held at the asked precision), or Mitsuba runs a variant the
    table BSDF cannot use (``scalar_rgb``).
    """
    ref = value["merl"]
    path = ctx.resolve(ref)
    try:
        table = read_merl(path, name=ref)
    except FormatError as exc:
        raise JobFailed(f"material.merl: {exc}") from None
    precision = value.get("table_precision") or "float32"
    try:
        return merl_bsdf(mi, table, precision=precision)
    except RuntimeError as exc:
        raise JobFailed(f"material.merl: {exc}") from None
    except ValueError as exc:
        raise JobFailed(f"material.table_precision: {ref}: {exc}") from None


register_material_source(
    "merl",
    resolve_merl,
    value_type=Ref,
    siblings=MerlSiblings,
    summary="A MERL BRDF table (.binary) by artifact reference, 'sha256:<digest>' or "
    "'job:<id>/<name>'; rendered with matforge's interpolating table BSDF; optional "
    "'table_precision': 'float32' (default) | 'float16' | 'rgb9e5'.",
)
