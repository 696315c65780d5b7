"""Named presets with per-field overrides, the one way a kind offers them.

A kind with presets declares a frozen dataclass of defaults and a dict of named instances
(``{"small": ..., "paper": ...}``); its params model has a ``preset`` field and one optional
field per tunable value (``None``: take the preset's). Then::

    steps: int | None = Field(default=None, description="Steps" + preset_note(PRESETS, "steps"))
    ...
    def effective(self) -> TrainPreset:
        return resolve_preset(self, PRESETS)

and the runner reads ``params.effective().steps``: a typed attribute of the preset's
dataclass, so a misspelled name is a type error (mypy), not a runtime ``AttributeError``.

Every kind with presets has a ``small`` one that runs in seconds to minutes on 2 cores
(tests, CI, ``make demo``) and a ``paper`` one at the paper's scale.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Mapping
from typing import Any, TypeVar

from pydantic import BaseModel

P = TypeVar("P")


def preset_note(presets: Mapping[str, Any], name: str) -> str:
    """The description suffix naming each preset's value of ``name``:
    ``"; unset: the preset's (small 32, paper 64)."``."""
    values = ", ".join(f"{k} {getattr(p, name)}" for k, p in presets.items())
    return f"; unset: the preset's ({values})."


def resolve_preset(
    params: BaseModel,
    presets: Mapping[str, P],
    *,
    key: str = "preset",
    keep: Collection[str] = (),
) -> P:
    """The preset that ``params.<key>`` names (a frozen dataclass instance), with each of its
    fields replaced by the params field of the same name where that field is set (not
    ``None``).

    Fields the params model does not declare stay the preset's, as do those named in
    ``keep`` (fields whose params counterpart has another type, which the kind resolves
    itself). A JSON list becomes a tuple, as the frozen dataclasses declare their sequences.
    """
    base = presets[getattr(params, key)]
    if not dataclasses.is_dataclass(base) or isinstance(base, type):
        raise TypeError(f"presets must be dataclass instances, got {type(base).__name__}")
    declared = type(params).model_fields
    changes: dict[str, Any] = {}
    for field in dataclasses.fields(base):
        if field.name in keep or field.name not in declared:
            continue
        value = getattr(params, field.name)
        if value is not None:
            changes[field.name] = tuple(value) if isinstance(value, list) else value
    return dataclasses.replace(base, **changes)
