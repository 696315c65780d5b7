"""``render.json`` of ``render``: the one definition of the document.

:func:`evaluators.render.kind.run_render` builds it; ``put_json`` validates it against
:class:`RenderDocument`; the summary reads it with :func:`jobapi.documents.read_typed`; the
kinds reference lists its fields.
"""

from __future__ import annotations

from typing import Any

from typing_extensions import TypedDict

from jobapi.documents import document


@document
class RenderPass(TypedDict):
    """One render pass."""

    spp: int
    """Its samples per pixel."""
    seed: int
    """Its sampler seed."""


@document
class RenderRenderer(TypedDict):
    """What rendered the image."""

    mitsuba: str
    """Mitsuba's version."""
    variant: str | None
    """Its variant."""


@document
class RenderPreview(TypedDict):
    """How ``preview.png`` was made from the image."""

    curve: str
    """The tone curve."""
    exposure: float
    """Exposure, stops."""
    encoding: str
    """The transfer function."""


@document
class RenderImage(TypedDict):
    """Figures of ``image.exr``."""

    width: int
    """Pixels."""
    height: int
    """Pixels."""
    mean_rgb: list[float]
    """Mean linear RGB."""
    max: float
    """Largest value."""


@document
class RenderDocument(TypedDict):
    """``render.json`` of ``render``: the settings as rendered and the image's figures."""

    scene: str
    """The scene."""
    material: dict[str, Any]
    """The material, as given."""
    resolution: list[int]
    """``[width, height]``."""
    spp: int
    """Samples per pixel, all passes."""
    max_depth: int
    """The integrator's path depth."""
    camera: dict[str, Any]
    """The scene's camera."""
    point_lights: list[dict[str, Any]]
    """The scene's point lights."""
    environment: str | None
    """The environment map (``null``: none)."""
    integrator: str
    """The Mitsuba integrator (``path``, ``fabric_path``, ...)."""
    sampler: str
    """The sampler."""
    rfilter: str
    """The reconstruction filter."""
    passes: list[RenderPass]
    """The passes, each with its seed."""
    renderer: RenderRenderer
    """What rendered it."""
    preview: RenderPreview
    """How the preview was made."""
    image: RenderImage
    """The image's figures."""
