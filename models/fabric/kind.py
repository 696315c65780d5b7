"""The ``train.fabric`` job kind: the neural woven-fabric model of Chen, Wang & Wang 2024.

An encoder (ResNet-18 without its last stage over the normal and orientation maps, plus
the appearance parameters, through a residual MLP) gives each material a 64-d latent; a
decoder (one-blob footprint encoding, spatial fusion, a 5-layer angular decoder with a
skip) maps latent and query to ``C_warp, C_weft, S_warp, S_weft`` (Eq. 7); Eq. 8 recombines
them with the albedos. Architecture: :mod:`models.fabric.networks`; loss Eq. 9-11:
:mod:`models.fabric.losses`; SGD of Sec. 5.2: :mod:`models.fabric.train`; data from a
``generate.fabric`` job: :mod:`models.fabric.data`.

Artifacts:

- ``model.pt``: torch checkpoint, the whole network's state dict (encoder included) and the
  config (:func:`models.fabric.portable.checkpoint_bytes`);
- ``model.json``: the portable model, format ``matforge.fabric-model/1``
  (:mod:`models.fabric.portable`): architecture, decoder weights as lists, every training
  material's latent and parameters; the fused Dr.Jit decoder
  (:mod:`models.fabric.fused`) reads it;
- ``latents.json``: material name -> latent (64 floats) and its ``materials.json`` params;
- ``curves.json``, ``curves.png``: Eq. 11 (and each component's MSE) against step;
- ``metrics.json``: per material, on its held-out queries: MSE and relative L1 error of each
  component and of the Eq. 8 RGB value, the Eq. 11 loss, and the same figures for a trivial
  baseline (the material's per-component training mean); means over materials
  (:mod:`models.fabric.report`); for a dataset with held-out sets (``generate.fabric``'s
  ``unseen*`` presets: only ``train`` materials are trained on) each row's ``split`` and
  ``sets``, the figures per split with their spread (:func:`models.fabric.report.split_sets`).

Same spec, same bytes: every artifact, on the CPU (``device`` ``cpu``, or ``auto`` on a
machine without CUDA). No artifact holds a timing (the last progress message and the log
line do). With ``auto`` on a CUDA machine training runs there, which is not bit-exact.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field

from jobapi.documents import CurvesDocument, read_typed
from jobapi.kinds import Figure, Kind, register
from jobapi.params import Device, JobRef, Ref, StrictModel, device_field
from jobapi.presets import preset_note, resolve_preset
from jobapi.reports import ReportFacts
from jobapi.results import ArtifactReader, ResultTable, per_material_table
from models.fabric.claims import fabric_claims
from models.fabric.document import FabricLatents, FabricModelDocument, TrainFabricMetrics
from models.fabric.rows import train_fabric_rows

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: ``job:<id>`` of a ``generate.fabric`` job.
DatasetJob = JobRef


@dataclass(frozen=True)
class FabricPreset:
    """Defaults of every tunable field."""

    summary: str
    encoder_width: int
    decoder_width: int
    map_resolution: int
    steps: int
    batch: int
    materials_per_step: int
    lr: float
    momentum: float
    weight_decay: float
    clip: float
    holdout: float
    train_queries: int | None
    loss: str = "paper"
    centre_encoding: str = "one_blob"
    size_encoding: str = "strata"
    centre_bins: int = 8
    phase_channels: int = 0
    param_skip: bool = False


#: ``small``: ~2 minutes on 2 shared cores for the small generate.fabric dataset.
#: ``medium``: the second pass of issue 12 (unbiased loss, log size, periodic centre, phase
#: features) in about 22 minutes on 2 idle cores: 45,000 steps, each 1.06x a ``small`` step
#: (measured side by side) of 27-29 ms (BENCHMARKS.md); for a dataset like the Sec. 6
#: recipe's (log-uniform sizes recommended).
#: ``paper``: Sec. 5.2, 10 epochs over 160 M queries in batches of 512 = 3,125,000 steps
#: (4 days on an RTX 3090 in the paper); for a GPU.
PRESETS: dict[str, FabricPreset] = {
    "small": FabricPreset(
        "~2 min on 2 cores for the small generate.fabric dataset (3 materials)",
        encoder_width=32, decoder_width=32, map_resolution=64, steps=3000, batch=512,
        materials_per_step=4, lr=0.05, momentum=0.9, weight_decay=1e-5, clip=1.0,
        holdout=0.1, train_queries=None,
    ),
    "medium": FabricPreset(
        "~22 min on 2 idle cores: relative L2, log size, periodic centre, phase features",
        encoder_width=32, decoder_width=48, map_resolution=64, steps=45_000, batch=512,
        materials_per_step=4, lr=0.05, momentum=0.9, weight_decay=1e-5, clip=1.0,
        holdout=0.1, train_queries=None, loss="relative_l2", centre_encoding="periodic",
        size_encoding="log", centre_bins=16, phase_channels=8,
    ),
    "paper": FabricPreset(
        "Sec. 5.2: SGD lr 5e-2, x0.2 at 60 % and 90 %, batch 512, 3.125 M steps; for a GPU",
        encoder_width=64, decoder_width=64, map_resolution=256, steps=3_125_000, batch=512,
        materials_per_step=8, lr=0.05, momentum=0.9, weight_decay=1e-5, clip=1.0,
        holdout=0.01, train_queries=344_000,
    ),
}  # fmt: skip


def _preset(name: str) -> str:
    return preset_note(PRESETS, name)


class TrainFabricParams(StrictModel):
    """Parameters of ``train.fabric``; a field left out takes the ``preset``'s value.

    ======================  ==============  ========  ========  ===============================
    name                    type            small     paper     meaning
    ======================  ==============  ========  ========  ===============================
    ``dataset``             ``job:<id>``    required            a generate.fabric job
    ``preset``              small | paper   small               defaults below
    ``encoder_width``       16..64          32        64        ResNet base width (64: ResNet-18)
    ``decoder_width``       16..128         32        64        decoder hidden width
    ``map_resolution``      32..512         64        256       encoder input maps, px
    ``steps``               int             3000      3125000   SGD steps
    ``batch``               int             512       512       queries per step
    ``materials_per_step``  int             4         8         materials drawn per step
    ``lr``                  float           0.05      0.05      x0.2 at 60 % and 90 %
    ``momentum``            float           0.9       0.9       SGD momentum
    ``weight_decay``        float           1e-5      1e-5      L2 on every weight
    ``clip``                float           1.0       1.0       gradient-norm clip
    ``holdout``             float           0.1       0.01      held-out query fraction
    ``train_queries``       int             all       344000    training queries kept
    ``held_out_beta``       list of floats  none      none      betas never trained on
    ``loss``                paper | rel.    paper     paper     Eq. 9-11, or relative_l2
    ``centre_encoding``     one_blob|per.   one_blob  one_blob  periodic: no seam at the border
    ``size_encoding``       strata | log    strata    strata    log: resolves small footprints
    ``centre_bins``         4..64           8         8         bins per centre coordinate
    ``phase_channels``      0..32           0         0         phase-aware features (0: off)
    ``param_skip``          bool            false     false     alpha, beta, w to the decoder
    ``device``              auto|cpu|cuda   auto      auto      auto: cuda if available
    ======================  ==============  ========  ========  ===============================

    The ``medium`` preset (~22 min on 2 idle cores) is ``small``'s with ``decoder_width``
    48, 45,000 steps, ``loss`` relative_l2, ``centre_encoding`` periodic with 16
    ``centre_bins``, ``size_encoding`` log and 8 ``phase_channels`` (issue 12).

    Example::

        {"kind": "train.fabric", "seed": 0, "params": {"dataset": "job:<generate.fabric id>",
         "preset": "small"}}
    """

    dataset: DatasetJob = Field(
        description="'job:<id>' of a succeeded generate.fabric job (in a batch file "
        "'step:<name>'): its shards, maps and materials.json."
    )
    preset: Literal["small", "medium", "paper"] = Field(
        default="small",
        description="Defaults of the unset fields: 'small' (~2 min on 2 cores), 'medium' "
        "(~22 min on 2 idle cores, the issue-12 options on) or 'paper' (Sec. 5.2, 3.125 M steps; "
        "for a GPU).",
    )
    encoder_width: int | None = Field(
        default=None, ge=16, le=64, multiple_of=8,
        description="ResNet base width; layer3 has 4x this many channels"
        + _preset("encoder_width"),
    )  # fmt: skip
    decoder_width: int | None = Field(
        default=None, ge=8, le=128,
        description="Hidden width of the spatial and angular decoder" + _preset("decoder_width"),
    )  # fmt: skip
    map_resolution: int | None = Field(
        default=None, ge=16, le=512,
        description="Pixels per side of the encoder's normal and orientation maps (the "
        "dataset's maps are resampled)" + _preset("map_resolution"),
    )  # fmt: skip
    steps: int | None = Field(
        default=None, ge=1, le=10_000_000, description="SGD steps" + _preset("steps")
    )
    batch: int | None = Field(
        default=None, ge=8, le=65536, description="Queries per step" + _preset("batch")
    )
    materials_per_step: int | None = Field(
        default=None, ge=1, le=256,
        description="Distinct materials drawn per step (at most all)"
        + _preset("materials_per_step"),
    )  # fmt: skip
    lr: float | None = Field(
        default=None, gt=0.0, le=1e4,
        description="SGD learning rate, x0.2 after 60 % and 90 % of the steps" + _preset("lr"),
    )  # fmt: skip
    momentum: float | None = Field(
        default=None, ge=0.0, lt=1.0, description="SGD momentum" + _preset("momentum")
    )
    weight_decay: float | None = Field(
        default=None, ge=0.0, le=1.0,
        description="L2 regularisation of every weight" + _preset("weight_decay"),
    )  # fmt: skip
    clip: float | None = Field(
        default=None, gt=0.0, le=1e6, description="Gradient-norm clip" + _preset("clip")
    )
    holdout: float | None = Field(
        default=None, ge=0.0, le=0.5,
        description="Fraction of each material's queries held out for metrics.json (fixed "
        "seed, never trained on)" + _preset("holdout"),
    )  # fmt: skip
    held_out_beta: list[Annotated[float, Field(ge=0.0, le=2.0)]] | None = Field(
        default=None, min_length=1, max_length=64,
        description="Beta values held out whole: a material whose beta (equal for warp and "
        "weft, within 1e-6) is listed is never trained on, only scored (its held-out "
        "queries, as the others') and marked `held_out` in metrics.json, whose "
        "`beta_response` gives per pattern with two or more such betas the slope of each "
        "component's mean against beta, the network's beside Monte Carlo's. Meant for "
        "generate.fabric's `beta` preset (16 betas per pattern from 0.1 to 1 in steps of "
        "0.06; e.g. [0.4, 0.7]). Default: none.",
    )  # fmt: skip
    train_queries: int | None = Field(
        default=None, ge=1, le=1 << 26,
        description="Most training queries kept per material (a fixed-seed uniform subset; "
        "Sec. 5.2 trains on about 160 M of the data set's queries, 344,000 per material); "
        "unset: the preset's (small all, paper 344000).",
    )  # fmt: skip
    loss: (
        Literal[
            "paper", "relative_l2", "relative_l2_mean", "relative_l2_stderr",
            "relative_l2_meanterm",
        ]
        | None
    ) = Field(  # fmt: skip
        default=None,
        description="Training loss: 'paper' (Eq. 9-11: specular in log space, which fits "
        "E[ln(1 + kS)] and so biases S low) or 'relative_l2' (unbiased in linear units: "
        "(p - y)^2 / (sg(p)^2 + m^2), minimised by the conditional mean; C and S balanced) or "
        "'relative_l2_mean' (the same with Monte Carlo standard errors in the denominators "
        "and a term holding each material's mean per component and light side), or each "
        "addition alone: 'relative_l2_stderr' (the standard errors only), "
        "'relative_l2_meanterm' (the mean term only); metrics.json reports both the Eq. 11 "
        "and the relative L2 figures" + _preset("loss"),
    )  # fmt: skip
    centre_encoding: Literal["one_blob", "periodic"] | None = Field(
        default=None,
        description="Footprint centre encoding: 'one_blob' (Sec. 4.2) or 'periodic' (the "
        "one-blob with distances wrapped at the tile border: no seam)"
        + _preset("centre_encoding"),
    )  # fmt: skip
    size_encoding: Literal["strata", "log"] | None = Field(
        default=None,
        description="Footprint size mapping before the one-blob: 'strata' (each Sec. 5.1 "
        "stratum half the range) or 'log' (0.01 to 5 tiles on a log scale)"
        + _preset("size_encoding"),
    )  # fmt: skip
    centre_bins: int | None = Field(
        default=None, ge=4, le=64,
        description="One-blob bins per centre coordinate" + _preset("centre_bins"),
    )  # fmt: skip
    phase_channels: int | None = Field(
        default=None, ge=0, le=32,
        description="Phase-aware features: channels of the encoder's stride-8 feature map "
        "sampled (bilinear, wrapping) at the footprint centre and fed to the decoder; 0: off"
        + _preset("phase_channels"),
    )  # fmt: skip
    param_skip: bool | None = Field(
        default=None,
        description="Hand the 5 appearance parameters (alpha, beta per yarn, w) to the "
        "decoder beside the latent (they join each material's code); without it a small "
        "model learns one function per pattern (at 6,000 steps it does so with this on too; "
        "BENCHMARKS.md)" + _preset("param_skip"),
    )  # fmt: skip
    init: Ref | None = Field(
        default=None,
        description="model.pt of a previous train.fabric job with the same architecture: "
        "its weights start this fit (fine-tuning).",
    )
    device: Device = device_field("auto")

    def effective(self) -> FabricPreset:
        """The preset with the set fields in its place."""
        return resolve_preset(self, PRESETS)


def run_train_fabric(params: TrainFabricParams, ctx: JobContext) -> None:
    """Train, score and store the model (see the module docstring)."""
    from models.fabric.runner import train_and_report

    train_and_report(params, ctx)


#: Columns of ``metrics.json``'s per-material rows, in the result table: held-out errors
#: against the Monte Carlo estimates (``baseline.*``: the per-material mean predictor).
FABRIC_COLUMNS = (
    "pattern",
    "queries",
    "loss",
    "baseline.loss",
    "relative_l2",
    "rgb.rel",
    "baseline.rgb.rel",
    "rgb.mse",
    "C_warp.rel",
    "C_weft.rel",
    "S_warp.rel",
    "S_weft.rel",
)


def summarize(read: ArtifactReader) -> ResultTable | None:
    """The result table: ``metrics.json`` (read typed), one row per material then the mean."""
    return per_material_table(read_typed(read("metrics.json"), TrainFabricMetrics), FABRIC_COLUMNS)


register(
    Kind(
        name="train.fabric",
        params=TrainFabricParams,
        runner=run_train_fabric,
        description="Train the neural woven-fabric model (Chen et al. 2024: ResNet encoder, "
        "one-blob spatial + angular decoder, Eq. 9-11) on a generate.fabric dataset.",
        artifacts=(
            "model.pt",
            "model.json",
            "latents.json",
            "curves.json",
            "curves.png",
            "metrics.json",
        ),
        smoke={
            "dataset": "step:generate.fabric",
            "encoder_width": 16,
            "decoder_width": 16,
            "map_resolution": 32,
            "steps": 3,
            "batch": 32,
            "materials_per_step": 1,
        },
        figures=(
            Figure(
                "curves.png",
                caption="Training curves (the Charts section draws them interactively).",
                lead=True,
            ),
        ),
        documents={
            "curves.json": CurvesDocument,
            "metrics.json": TrainFabricMetrics,
            "model.json": FabricModelDocument,
            "latents.json": FabricLatents,
        },
        summary=summarize,
        rows=train_fabric_rows,
        metrics=("loss", "relative_l2", "*.mse", "*.rel", "*.ratio"),
        # the headline: the network's rows (its Monte Carlo baselines have rows too)
        report=ReportFacts(metric="rgb.rel", candidate="network", claims=fabric_claims),
    )
)
