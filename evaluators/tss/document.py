"""The documents of ``evaluate.tss``: ``metrics.json`` (:class:`TssMetrics`), ``timing.json``
(:class:`TssTiming`) and ``path.json`` (:class:`TssPath`), each defined once here.

:func:`evaluators.tss.kind.metrics_document`, :func:`evaluators.tss.kind.timing_document`
and :meth:`evaluators.tss.path.CameraPath.document` build them; ``put_json`` validates them
against these types; the summary and the result rows read them with
:func:`jobapi.documents.read_typed`; the kinds reference lists their fields.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field
from typing_extensions import TypedDict

from jobapi.documents import document


@document
class TssModel(TypedDict):
    """The model evaluated."""

    job: str | None
    """Its ``job:<id>`` (a ``train.btf`` job), or ``null`` for a user's model."""
    external: dict[str, Any] | None
    """A user's model: the ``external`` source as given (``null``: a job's model)."""
    runtime: str
    """What evaluated it (``drjit-fused``, ``onnxruntime``)."""
    model: str
    """Its type (``neumip``, ``c2f``, ``lafortune``, a user's)."""
    kind: str
    """Its architecture kind."""
    resolution: list[int]
    """Its texture resolution ``[H, W]``."""


# One row: ``pass`` is a Python keyword, so the functional form names the fields (each
# described by its ``Field``, as the docs' table reads them).
TssRow = TypedDict(
    "TssRow",
    {
        "label": Annotated[str, Field(description="``\"<R>/N=<N>\"``: the row's name (the key "
                                                  "of ``timing.json``'s ``rows``).")],
        "resolution": Annotated[int, Field(description="The radiance texture's side R, texels.")],
        "interval": Annotated[int, Field(description="The shading interval N: the texture is "
                                                     "shaded every N + 1 frames.")],
        "pass": Annotated[str, Field(description="``amortised`` (the coarse MLP once per 2 x 2 "
                                                 "block) or ``per_texel`` (every texel alone).")],
        "flip_mean": Annotated[float, Field(description="Mean over frames of each frame's mean "
                                                        "FLIP against its reference.")],
        "flip_max": Annotated[float, Field(description="Largest per-frame mean FLIP.")],
        "psnr_mean": Annotated[float | None, Field(description="Mean PSNR, dB (``null`` when a "
                                                   "frame equals its reference: infinite).")],
        "psnr_min": Annotated[float | None, Field(description="Least PSNR, dB (``null``: "
                                                              "infinite).")],
        "shading_passes": Annotated[int, Field(description="Shading passes run over the "
                                                           "frames.")],
    },
)  # fmt: skip
document(TssRow)


@document
class TssFigure(TypedDict):
    """The frame and interval of ``frames.png``."""

    frame: int
    """The frame shown."""
    interval: int
    """The interval whose frame is shown beside the reference."""


@document
class TssMotion(TypedDict):
    """The camera path's motion between consecutive frames (0 for a single frame)."""

    translation_mm_mean: float
    """Mean eye travel, mm."""
    translation_mm_max: float
    """Largest eye travel, mm."""
    rotation_deg_mean: float
    """Mean view rotation, degrees."""
    rotation_deg_max: float
    """Largest view rotation, degrees."""


@document
class TssMetrics(TypedDict):
    """``metrics.json`` of ``evaluate.tss``: everything deterministic of the run."""

    format: str
    """The document's format."""
    model: TssModel
    """The model evaluated."""
    rows: list[TssRow]
    """One per texture resolution and shading interval."""
    per_frame: dict[str, dict[str, list[float | None]]]
    """``{row label: {"flip": [...], "psnr": [...]}}``, one value per frame."""
    motion: TssMotion
    """The camera path's motion figures."""
    figure: TssFigure
    """The frame and interval of the figure."""
    settings: dict[str, Any]
    """The run's settings (frames, image, lights, path, texture pass, FLIP)."""


@document
class TssCost(TypedDict):
    """One row's measured cost."""

    seconds_per_frame: float
    """Median shading-pass kernel seconds / (N + 1) + median lookup-pass kernel seconds."""
    relative_cost: float | None
    """``seconds_per_frame`` over the screen-space pass's (``null``: not finite)."""
    wall_seconds_per_frame: float
    """The same from wall time."""
    wall_relative_cost: float | None
    """The same from wall time."""


@document
class TssPassTime(TypedDict):
    """The median seconds of one pass."""

    kernel_s: float
    """Dr.Jit kernel seconds."""
    wall_s: float
    """Wall seconds."""
    count: int
    """Passes timed."""


@document
class TssPasses(TypedDict):
    """The median seconds of each pass."""

    screen_space: TssPassTime
    """The per-frame screen-space reference pass."""
    shading: dict[str, TssPassTime]
    """``{R: times}``: the texture's shading pass."""
    lookup: dict[str, TssPassTime]
    """``{R: times}``: the screen pass that looks the texture up."""


@document
class TssTiming(TypedDict):
    """``timing.json`` of ``evaluate.tss``: the measured costs (they vary between runs)."""

    format: str
    """The document's format."""
    rows: dict[str, TssCost]
    """``{row label: cost}``, the labels of ``metrics.json``'s rows."""
    passes: TssPasses
    """Each pass's median seconds."""
    environment: dict[str, Any]
    """Where the numbers were taken: CPU, threads, load average, versions."""
    units: dict[str, str]
    """What each cost is."""
    note: str
    """That the document varies from run to run."""


@document
class TssPath(TypedDict):
    """``path.json`` of ``evaluate.tss``: the seeded head path's cameras."""

    convention: str
    """The camera convention (world z up; basis rows right, up, forward; pinhole)."""
    tan_half_fov: float
    """``tan(fov_x / 2)``."""
    eye: list[list[float]]
    """Per frame the eye position ``[x, y, z]``, metres."""
    basis: list[list[list[float]]]
    """Per frame the camera basis, rows right, up, forward."""
    motion: TssMotion
    """The path's motion figures."""
    shading_frames: dict[str, list[int]]
    """``{N: frames}``: the frames whose texture was shaded, per interval."""
