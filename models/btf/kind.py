"""The ``train.btf`` job kind: neural BTF models and their baselines (Xu et al. 2025).

Models (``model``):

- ``neumip``: the modified NeuMIP (no offset module, one texture at the finest level), 25
  wide; ``width`` 8 gives the same-capacity variant of Fig. 8;
- ``neumip_max``: NeuMIP 128 wide, the teacher (the paper's "NeuMIP Max");
- ``c2f``: the coarse-to-fine student of Sec. 4.1 (8 wide), with ``distill`` the
  distillation of Eq. 5 from a trained ``neumip_max`` job;
- ``lafortune``: a diffuse colour and 4 Lafortune lobes per texel, fitted by
  Levenberg-Marquardt (Sec. 5.3).

Artifacts: ``model.json`` + ``textures.npz`` (the portable model,
:mod:`models.btf.portable`); ``metrics.json`` (the L1 over the whole BTF as in Table 1,
over the training and held-out slices, and the storage); ``curves.json`` and
``curves.png`` (networks: loss and held-out L1 per epoch); ``reconstructions.png``
(held-out slices: truth, model, error, as Fig. 8).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Literal

from pydantic import Field, SerializerFunctionWrapHandler, model_serializer, model_validator

from jobapi.documents import CurvesDocument, read_typed
from jobapi.kinds import Figure, Kind, register
from jobapi.params import Device, JobRef, StrictModel, device_field
from jobapi.presets import preset_note, resolve_preset
from jobapi.reports import ReportFacts
from jobapi.results import ArtifactReader, ResultTable
from models.btf.document import BtfModelDocument, TrainBtfMetrics
from models.btf.rows import train_btf_rows

if TYPE_CHECKING:
    from jobapi.context import JobContext


@dataclass(frozen=True)
class BtfTrainPreset:
    """Defaults of the tunable fields."""

    epochs: int
    teacher_epochs: int
    plateau_steps: int | None
    holdout: float
    lafortune_iterations: int
    lafortune_slices: int | None


#: ``small``: seconds to a few minutes on 2 cores for a small generate.btf (36 slices of
#: 32^2). ``paper``: Sec. 4.4, the teacher ~60 epochs and the student at most 150; for a
#: GPU at UBO2014's 151 x 151 x 400^2.
PRESETS: dict[str, BtfTrainPreset] = {
    "small": BtfTrainPreset(epochs=150, teacher_epochs=60, plateau_steps=1024, holdout=0.1,
                            lafortune_iterations=40, lafortune_slices=None),
    "paper": BtfTrainPreset(epochs=150, teacher_epochs=60, plateau_steps=None, holdout=0.05,
                            lafortune_iterations=60, lafortune_slices=1024),
}  # fmt: skip

#: Default MLP width of each network model.
WIDTHS = {"neumip": 25, "neumip_max": 128, "c2f": 8}


class DistillSpec(StrictModel):
    """Eq. 5's teacher and weights."""

    teacher: JobRef = Field(
        description="'job:<id>' of a succeeded train.btf job of a NeuMIP model (the paper: "
        "neumip_max) trained on the same BTF."
    )
    sigma: float = Field(default=0.1, ge=0.0, le=10.0, description="Weight of L1(y_s, y_t).")
    lambda1: float = Field(default=0.1, ge=0.0, le=10.0, description="Weight of the 1st tap.")
    lambda2: float = Field(default=0.1, ge=0.0, le=10.0, description="Weight of the 2nd tap.")
    hint: Literal["mse", "standardised"] = Field(
        default="mse",
        description="Form of the two feature-hint terms: 'mse' (the mean squared error, "
        "the default, the form earlier specs ran with) or 'standardised' (each feature "
        "standardised over the slice before the squared error: scale-invariant and of order "
        "1, so lambda weighs it against L1; see models.btf.train).",
    )

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        # The default hint is left out, so a spec written before the field existed keeps
        # its canonical form and its hash (and its bytes: 'mse' is what it ran with).
        data: dict[str, Any] = handler(self)
        if data.get("hint") == "mse":
            del data["hint"]
        return data


class TrainBtfParams(StrictModel):
    """Parameters of ``train.btf``; a field left out takes the ``preset``'s value.

    ==========================  ============  ===========================================
    name                        default       meaning
    ==========================  ============  ===========================================
    ``data``                    required      a generate.btf or import.btf job
    ``model``                   required      neumip | neumip_max | c2f | lafortune
    ``width``                   model's       MLP width (25, 128, 8)
    ``distill``                 none          c2f: the teacher and Eq. 5's weights
    ``epochs``                  preset        passes over the training slices
    ``plateau_steps``           preset        steps between scheduler steps
    ``check_steps``             plateau       steps between curve points
    ``holdout``                 preset        fraction of slices held out (fixed choice)
    ``lafortune_iterations``    preset        Levenberg-Marquardt iterations
    ``lafortune_slices``        preset        slices the fit uses (all when unset)
    ``preset``                  small         small | paper
    ``device``                  auto          auto | cpu | cuda (lafortune: always cpu)
    ==========================  ============  ===========================================

    Example::

        {"kind": "train.btf", "seed": 0, "params": {"data": "job:<generate.btf id>",
         "model": "c2f", "distill": {"teacher": "job:<train.btf neumip_max id>"}}}
    """

    data: JobRef = Field(
        description="'job:<id>' of a succeeded generate.btf or import.btf job (in a batch "
        "file 'step:<name>')."
    )
    model: Literal["neumip", "neumip_max", "c2f", "lafortune"] = Field(
        description="neumip (25 wide), neumip_max (128, the teacher), c2f (the 8-wide "
        "coarse-to-fine student) or lafortune (4 lobes per texel)."
    )
    width: int | None = Field(
        default=None, ge=4, le=256,
        description="MLP width (default: neumip 25, neumip_max 128, c2f 8).",
    )  # fmt: skip
    distill: DistillSpec | None = Field(
        default=None, description="Distillation from a trained teacher (Eq. 5); c2f only."
    )
    preset: Literal["small", "paper"] = Field(
        default="small", description="Defaults of the unset fields: 'small' or 'paper'."
    )
    epochs: int | None = Field(
        default=None, ge=1, le=100_000,
        description="Epochs (one step per training slice)" + preset_note(PRESETS, "epochs")
        + " neumip_max defaults to teacher_epochs" + preset_note(PRESETS, "teacher_epochs"),
    )  # fmt: skip
    plateau_steps: int | None = Field(
        default=None, ge=1, le=10_000_000,
        description="Steps between ReduceLROnPlateau steps on the held-out L1; unset: the "
        "preset's (small 1024, paper once per epoch as in Sec. 4.4)",
    )  # fmt: skip
    check_steps: int | None = Field(
        default=None, ge=1, le=10_000_000,
        description="Steps between points of the curves (held-out L1); unset: at the "
        "scheduler's steps",
    )  # fmt: skip
    device: Device = device_field("auto")

    def effective(self) -> BtfTrainPreset:
        """The preset with the set fields in its place; ``neumip_max`` (the teacher) takes
        ``teacher_epochs`` when ``epochs`` is unset."""
        eff = resolve_preset(self, PRESETS)
        if self.epochs is None and self.model == "neumip_max":
            eff = replace(eff, epochs=eff.teacher_epochs)
        return eff

    holdout: float | None = Field(
        default=None, ge=0.0, le=0.5,
        description="Fraction of slices held out" + preset_note(PRESETS, "holdout"),
    )  # fmt: skip
    lafortune_iterations: int | None = Field(
        default=None, ge=1, le=1000,
        description="Levenberg-Marquardt iterations"
        + preset_note(PRESETS, "lafortune_iterations"),
    )  # fmt: skip
    lafortune_slices: int | None = Field(
        default=None, ge=16, le=151 * 151,
        description="Training slices the Lafortune fit reads (evenly spaced); unset: the "
        "preset's (small: all, paper: 1024)",
    )  # fmt: skip

    def network_width(self) -> int:
        return int(self.width or WIDTHS[self.model])

    @model_validator(mode="after")
    def _check(self) -> TrainBtfParams:
        if self.distill is not None and self.model != "c2f":
            raise ValueError("distill applies to the c2f student only")
        if self.model == "lafortune" and self.width is not None:
            raise ValueError("width does not apply to lafortune")
        return self


def run_train_btf(params: TrainBtfParams, ctx: JobContext) -> None:
    """Train (or fit) the model and write its artifacts (:mod:`models.btf.runner`)."""
    from models.btf.runner import train_and_report

    train_and_report(params, ctx)


def summarize(read: ArtifactReader) -> ResultTable | None:
    """One row: the model's L1 (whole BTF, held-out) and storage (Table 1)."""
    doc = read_typed(read("metrics.json"), TrainBtfMetrics)
    if doc is None:
        return None
    row = {
        "l1": doc["l1"],
        "l1_heldout": doc["l1_heldout"],
        "relative_l1": doc["relative_l1"],
        "storage_bytes": doc["storage"]["total_bytes"],
        "network_bytes": doc["storage"]["network_bytes"],
    }
    return ResultTable(
        title="BTF model (Table 1)", label_header="Model", columns=list(row),
        rows={doc["label"]: row},
    )  # fmt: skip


register(
    Kind(
        name="train.btf",
        params=TrainBtfParams,
        runner=run_train_btf,
        description="Neural BTF models (Xu et al. 2025): the modified NeuMIP, the NeuMIP Max "
        "teacher, the coarse-to-fine student with distillation (Eq. 3-5), and the 4-lobe "
        "Lafortune baseline, trained on a generate.btf or import.btf job.",
        # curves.*: the networks' (not lafortune's); naming them gives the page live curves
        artifacts=(
            "model.json",
            "textures.npz",
            "metrics.json",
            "reconstructions.png",
            "curves.json",
            "curves.png",
        ),  # fmt: skip
        smoke={"data": "step:generate.btf", "model": "c2f", "epochs": 2},
        figures=(
            Figure(
                "reconstructions.png",
                caption="Held-out slices: truth, the model and their error (Fig. 8's layout).",
                lead=True,
            ),
        ),
        documents={
            "curves.json": CurvesDocument,
            "metrics.json": TrainBtfMetrics,
            "model.json": BtfModelDocument,
        },
        summary=summarize,
        rows=train_btf_rows,
        metrics=("l1", "l1_train", "l1_heldout", "relative_l1"),
        # failure cases (shadowed / specular slices, models.btf.cases) differ in scale:
        # compared by the relative L1
        report=ReportFacts(metric="l1", family_metric="relative_l1", loss_key="train_loss"),
    )
)
