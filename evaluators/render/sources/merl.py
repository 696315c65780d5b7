"""The ``merl`` material source: ``{"merl": REF}`` renders a MERL table.

``REF`` is an artifact reference (``"sha256:<digest>"`` or ``"job:<id>/<name>"``) to a MERL
``.binary`` file: an upload (``matforge import``) or a table written by another job. Inside
the job the reference is resolved to a verified store path, the file is read and validated
by :mod:`storage.formats.merl`, and the table becomes the ``merl_table`` BSDF of
:mod:`evaluators.render.bsdfs.merl_table` (interpolated lookup, importance sampling with a fitted
GGX lobe).

Errors are one line naming the reference: a malformed file fails the job with
``material.merl: <ref>: <what is wrong>``.

This module registers the source when imported; :mod:`evaluators.render.kind` imports it, so the
source exists wherever the ``render`` kind does.
"""

from __future__ import annotations

import types
from typing import TYPE_CHECKING, Any

from evaluators.render.bsdfs.merl_table import merl_bsdf
from evaluators.render.sources.common import register_material_source
from jobapi.errors import JobFailed
from jobapi.params import Ref
from storage.errors import FormatError
from storage.formats.merl import read_merl

if TYPE_CHECKING:
    from jobapi.context import JobContext


def resolve_merl(value: str, ctx: JobContext, mi: types.ModuleType) -> Any:
    """Resolve ``{"merl": value}`` to an instantiated ``merl_table`` BSDF (``mi.BSDF``).

    Raises :class:`JobFailed` when the reference does not resolve, the file is not a valid
    MERL table, or Mitsuba runs a variant the table BSDF cannot use (``scalar_rgb``).
    """
    path = ctx.resolve(value)
    try:
        table = read_merl(path, name=value)
    except FormatError as exc:
        raise JobFailed(f"material.merl: {exc}") from None
    try:
        return merl_bsdf(mi, table)
    except RuntimeError as exc:
        raise JobFailed(f"material.merl: {exc}") from None


register_material_source(
    "merl",
    resolve_merl,
    value_type=Ref,
    summary="A MERL BRDF table (.binary) by artifact reference, 'sha256:<digest>' or "
    "'job:<id>/<name>'; rendered with matforge's interpolating table BSDF.",
)
