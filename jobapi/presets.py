"""Named presets with per-field overrides, the one way a kind offers them.

A kind with presets declares a frozen dataclass of defaults and a dict of named instances
(``{"small": ..., "paper": ...}``); its params model has a ``preset`` field and one optional
field per tunable value (``None``: take the preset's). Then::

    steps: int | None = Field(default=None, description="Steps" + preset_note(PRESETS, "steps"))
    ...
    def value(self, name: str) -> Any:
        return preset_value(self, PRESETS, name)

Every kind with presets has a ``small`` one that runs in seconds to minutes on 2 cores
(tests, CI, ``make demo``) and a ``paper`` one at the paper's scale.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def preset_note(presets: Mapping[str, Any], name: str) -> str:
    """The description suffix naming each preset's value of ``name``:
    ``"; unset: the preset's (small 32, paper 64)."``."""
    values = ", ".join(f"{k} {getattr(p, name)}" for k, p in presets.items())
    return f"; unset: the preset's ({values})."


def preset_value(params: Any, presets: Mapping[str, Any], name: str, *, key: str = "preset") -> Any:
    """The field ``name`` of ``params``, or the value of the preset ``params.<key>`` names
    when the field is ``None`` (left out)."""
    value = getattr(params, name)
    if value is not None:
        return value
    return getattr(presets[getattr(params, key)], name)
