"""The ``device`` param of the training kinds: one shared type, resolved at job start.

Oracles: torch's own ``torch.cuda.is_available()`` and the registry's params models."""

from __future__ import annotations

import typing

import pytest
import torch

from jobapi.context import JobContext
from jobapi.errors import JobFailed
from jobapi.params import Device
from models.device import pick_device
from service import kinds


def test01_every_training_kind_has_the_shared_device_field() -> None:
    kinds.load_builtin()
    training = [k for name, k in kinds.all_kinds().items() if name.startswith("train.")]
    assert {k.name for k in training} >= {"train.brdf", "train.btf", "train.fabric"}
    for k in training:
        field = k.params.model_fields["device"]
        assert field.annotation == Device, k.name
        assert typing.get_args(Device) == ("auto", "cpu", "cuda")
    # train.brdf keeps its old default, so its specs' identity and bytes do not move.
    defaults = {k.name: k.params.model_fields["device"].default for k in training}
    assert defaults["train.brdf"] == "cpu" and defaults["train.btf"] == "auto"


def test02_auto_cpu_and_cuda(tmp_path) -> None:
    ctx = JobContext(job_id="0" * 32, seed=0, spec={}, store=None, jobs=None, workdir=tmp_path)  # type: ignore[arg-type]
    assert pick_device("cpu", ctx) == "cpu" and ctx.device == "cpu"
    auto = pick_device("auto", ctx)
    assert auto == ("cuda" if torch.cuda.is_available() else "cpu") == ctx.device
    if torch.cuda.is_available():
        assert pick_device("cuda") == "cuda"
        return
    with pytest.raises(JobFailed, match=r"^params.device: 'cuda' was asked for but torch"):
        pick_device("cuda", ctx)
