"""A whole ``stats.json`` of ``generate.glint`` (:class:`storage.formats.glint_stats.GlintStats`)
for tests of its readers."""

from __future__ import annotations

from typing import Any

from storage.formats.glint_stats import GlintStats


def glint_stats(size: int = 16, total: int = 5000, **top: Any) -> GlintStats:
    """An example of ``size``^2 texels whose data takes ``total`` bytes; ``top`` replaces
    top-level keys."""
    doc: dict[str, Any] = {
        "example": {"size": size, "type": "isotropic_noise", "cropped_from": None},
        "levels": 4,
        "ndf_resolution": 32,
        "extent": 0.3,
        "lobes": 1024,
        "precompute_seconds": 0.5,
        "bytes": {"ndf_maps": total - 1024, "lobes": 1024, "total": total},
        "reference": {
            "resolution": 512,
            "lobe_rate": 2,
            "lobes": 1 << 20,
            "bytes": 1 << 25,
            "note": "explicit",
        },  # fmt: skip
        "memory_ratio": total / (1 << 25),
        "note": "timings vary",
        **top,
    }
    return doc  # type: ignore[return-value]
