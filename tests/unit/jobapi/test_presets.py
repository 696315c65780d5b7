"""Typed presets (jobapi.presets.resolve_preset).

The reference for every kind with presets is the rule the kinds used before the typed
accessor, written out here independently: a params field that is set wins, else the preset's
value (``getattr(params, name)`` if not ``None``, else ``getattr(PRESETS[preset], name)``).
Each kind's ``effective()`` must agree with it field by field, for its smoke params and every
preset, so the typed objects change no value (and no byte of any artifact).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

import pytest
from pydantic import BaseModel

from evaluators.tss import params as tss_params
from generators.btf import params as btf_gen
from generators.fabric import params as fabric_gen
from generators.glint import params as glint_gen
from jobapi.presets import preset_note, resolve_preset
from models.brdf import kind as brdf_train
from models.btf import kind as btf_train
from models.fabric import kind as fabric_train
from service import kinds

#: (kind name, params module holding PRESETS and the params class, fields resolved apart).
PRESET_KINDS: dict[str, tuple[Any, tuple[str, ...]]] = {
    "generate.btf": (btf_gen, ("directions",)),
    "generate.glint": (glint_gen, ()),
    "generate.fabric": (fabric_gen, ("texture_sets", "shading_sets")),
    "train.brdf": (brdf_train, ()),
    "train.btf": (btf_train, ()),
    "train.fabric": (fabric_train, ()),
    "evaluate.tss": (tss_params, ()),
}


def _jobs(value: Any) -> Any:
    # A batch file's 'step:<name>' refs, as the worker sees them: whole-job refs.
    if isinstance(value, str) and value.startswith("step:"):
        return "job:" + "0" * 32
    if isinstance(value, dict):
        return {k: _jobs(v) for k, v in value.items()}
    return [_jobs(v) for v in value] if isinstance(value, list) else value


def _old_rule(params: BaseModel, presets: dict[str, Any], name: str) -> Any:
    value = getattr(params, name)
    return value if value is not None else getattr(presets[params.preset], name)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class _Preset:
    steps: int
    sizes: tuple[int, ...]
    note: str = "not a field"


class _Params(BaseModel):
    preset: Literal["a", "b"] = "a"
    steps: int | None = None
    sizes: list[int] | None = None


_PRESETS = {"a": _Preset(1, (2, 3)), "b": _Preset(10, (20,))}


def test01_unset_fields_take_the_preset() -> None:
    assert resolve_preset(_Params(), _PRESETS) == _PRESETS["a"]
    assert resolve_preset(_Params(preset="b"), _PRESETS) == _PRESETS["b"]


def test02_set_fields_win_and_lists_become_tuples() -> None:
    eff = resolve_preset(_Params(preset="b", steps=7, sizes=[5, 6]), _PRESETS)
    assert eff == _Preset(7, (5, 6))
    assert eff.note == "not a field"  # a preset field the params lack stays the preset's


def test03_keep_leaves_a_field_to_the_kind() -> None:
    eff = resolve_preset(_Params(steps=7, sizes=[9]), _PRESETS, keep=("sizes",))
    assert eff.steps == 7 and eff.sizes == (2, 3)


def test04_presets_must_be_dataclasses() -> None:
    with pytest.raises(TypeError, match="dataclass"):
        resolve_preset(_Params(), {"a": {"steps": 1}})


def test05_note_names_each_preset() -> None:
    assert preset_note(_PRESETS, "steps") == "; unset: the preset's (a 1, b 10)."


@pytest.mark.parametrize("name", sorted(PRESET_KINDS))
def test06_every_kind_agrees_with_the_old_rule(name: str) -> None:
    module, apart = PRESET_KINDS[name]
    kinds.load_builtin()
    kind = kinds.get_kind(name)
    presets = module.PRESETS
    for preset in presets:
        params = kind.params.model_validate({**_jobs(kind.smoke), "preset": preset})
        eff = params.effective()
        assert isinstance(eff, type(presets[preset]))
        for field in dataclasses.fields(eff):
            if field.name in apart or field.name not in type(params).model_fields:
                continue
            want = _old_rule(params, presets, field.name)
            teacher = name == "train.btf" and getattr(params, "model", None) == "neumip_max"
            if teacher and field.name == "epochs" and params.epochs is None:  # type: ignore[attr-defined]
                want = presets[preset].teacher_epochs
            got = getattr(eff, field.name)
            assert got == (tuple(want) if isinstance(want, list) else want), (name, field.name)


def test07_train_btf_teacher_takes_teacher_epochs() -> None:
    p = btf_train.TrainBtfParams.model_validate({"data": "job:" + "0" * 32, "model": "neumip_max"})
    assert p.effective().epochs == btf_train.PRESETS["small"].teacher_epochs
    p = btf_train.TrainBtfParams.model_validate({"data": "job:" + "0" * 32, "model": "neumip"})
    assert p.effective().epochs == btf_train.PRESETS["small"].epochs
