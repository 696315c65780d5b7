"""``render`` with ``{"merl": REF}``: a tabulated material renders like the material itself.

End to end through the real runner (:func:`service.submission.run_in_process`): a Mitsuba
material X is tabulated (:func:`materials.tabulate.tabulate_mitsuba`), written as a MERL
``.binary``, imported into the store (validated, as ``matforge import`` does), and the
sphere is rendered with ``{"merl": "sha256:..."}`` and with ``{"mitsuba": X}``.

Oracle: Mitsuba's own rendering of X. "Within Monte Carlo noise" is measured, not assumed:
each material is rendered twice with independent seeds (merl at seeds 1 and 2, Mitsuba at
3 and 4). The sphere is cut into 16 regions (4 rings of the angle between the surface
normal and the view direction, up to 75 degrees, times 4 image quadrants). For each region
and channel, ``delta`` is the difference of the two materials' region means (each averaged
over its two seeds), and its standard error comes from the seed-to-seed differences of
the same pixels, ``SE^2 = (sum (a1 - a2)^2 + sum (b1 - b2)^2) / (4 n^2)``: pixels are
independent, and ``(a1 - a2)^2 / 2`` estimates a pixel's variance without assuming the
table BSDF's noise equals Mitsuba's. Accepted: every ``|delta| <= 4 SE + 1 %`` (the 1 %
allows for tabulation error, measured at 0.07 % median in
``tests/unit/materials/test_merl_bsdf.py``) and RMS ``z = delta / SE`` at most 1.75 (about 1
under the null hypothesis; measured 0.5-1.4 for native-vs-native renders at these sizes).
The render noise is heavy-tailed (small bright studio lights), so region means are used
rather than per-pixel squared errors.

The test has power: the same statistic rejects a slightly different Mitsuba material
(conductor alpha 0.3 -> 0.27, plastic diffuse albedo -6 %).
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from evaluators.render.scenes import SPHERE_CAMERA
from materials.tabulate import tabulate_mitsuba
from service.settings import Settings
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.formats.merl import MEDIA_TYPE, MerlTable, write_merl
from storage.jobs import JobStore
from tests.helpers.mitsuba_probes import AU_03, PLASTIC_03

SIZE, SPP, MAX_DEPTH = 64, 64, 3
#: (material, a slightly different material the statistic must tell apart)
CASES = {
    "conductor": (AU_03, {**AU_03, "alpha": 0.27}),
    "plastic": (
        PLASTIC_03,
        {**PLASTIC_03, "diffuse_reflectance": {"type": "rgb", "value": [0.188, 0.47, 0.752]}},
    ),
}
Z_MAX, BIAS_ALLOWANCE, RMS_Z_MAX = 4.0, 0.01, 1.75


def sphere_regions(size: int) -> np.ndarray:
    """``(size, size)`` int region labels 0..15 of the sphere's pixels, -1 elsewhere.

    The default camera looks at the unit sphere from distance 4: a pixel ray at angle
    ``a`` off the axis meets the sphere where the normal is ``asin(4 sin a)`` away from the
    ray. Rings at 30, 45 and 60 degrees (pixels beyond 75 are left out: the silhouette mixes
    in the background) times 4 quadrants.
    """
    distance = float(np.linalg.norm(np.subtract(SPHERE_CAMERA.origin, SPHERE_CAMERA.target)))
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    px, py = np.meshgrid(c, -c)
    off_axis = np.arctan(np.hypot(px, py) * math.tan(math.radians(SPHERE_CAMERA.fov) / 2.0))
    sin_n = distance * np.sin(off_axis)
    theta_n = np.degrees(np.arcsin(np.clip(sin_n, 0.0, 1.0)))
    quadrant = np.floor(np.arctan2(py, px) / (np.pi / 2.0)).astype(int) % 4
    ring = np.digitize(theta_n, [30.0, 45.0, 60.0])
    return np.where((sin_n < 1.0) & (theta_n <= 75.0), ring * 4 + quadrant, -1)


def compare(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> dict[str, float]:
    """Region statistics of renders ``a`` (two seeds) against ``b`` (two other seeds)."""
    regions = sphere_regions(a[0].shape[0])
    excess, zs, rel = [], [], []
    for r in range(16):
        m = regions == r
        n = int(m.sum())
        mean_a = ((a[0] + a[1]) / 2.0)[m].mean(axis=0)
        mean_b = ((b[0] + b[1]) / 2.0)[m].mean(axis=0)
        se = np.sqrt(((a[0] - a[1])[m] ** 2).sum(0) + ((b[0] - b[1])[m] ** 2).sum(0)) / (2 * n)
        delta = mean_a - mean_b
        zs.append(delta / se)
        excess.append((np.abs(delta) - BIAS_ALLOWANCE * np.abs(mean_b)) / se)
        rel.append(delta / mean_b)
    z = np.concatenate(zs)
    return {
        "max_excess_z": float(np.max(excess)),
        "rms_z": float(np.sqrt(np.mean(z**2))),
        "max_abs_z": float(np.max(np.abs(z))),
        "max_rel_diff": float(np.max(np.abs(rel))),
    }


def accepted(stats: dict[str, float]) -> bool:
    return stats["max_excess_z"] <= Z_MAX and stats["rms_z"] <= RMS_Z_MAX


def render(settings: Settings, material: dict[str, Any], seed: int) -> np.ndarray:
    params = {"material": material, "resolution": [SIZE, SIZE], "spp": SPP, "max_depth": MAX_DEPTH}
    job = run_in_process({"kind": "render", "seed": seed, "params": params}, settings)
    assert job.state == "succeeded", job.error
    (image,) = [a for a in job.artifacts if a.name == "image.exr"]
    return read_exr(ArtifactStore(settings.store_dir).path(image.digest)).astype(np.float64)


@pytest.mark.parametrize("name", sorted(CASES))
def test01_merl_render_matches_mitsuba(
    name: str, settings: Settings, tmp_path: Path, mitsuba_llvm: None
) -> None:
    plugin, perturbed = CASES[name]
    table, _ = tabulate_mitsuba(plugin)
    path = tmp_path / f"{name}.binary"
    write_merl(path, table)
    jobs = JobStore(settings.db_path)
    try:
        record = import_file(path, jobs, ArtifactStore(settings.store_dir))
    finally:
        jobs.close()
    assert record.media_type == MEDIA_TYPE
    ref = f"sha256:{record.digest}"

    merl = tuple(render(settings, {"merl": ref}, seed) for seed in (1, 2))
    # The smallest table (shared-exponent words), through the spec's sibling key.
    small = {"merl": ref, "table_precision": "rgb9e5"}
    merl_small = tuple(render(settings, small, seed) for seed in (7, 8))
    native = tuple(render(settings, {"mitsuba": plugin}, seed) for seed in (3, 4))
    other = tuple(render(settings, {"mitsuba": perturbed}, seed) for seed in (5, 6))
    stats = compare(merl, native)  # type: ignore[arg-type]
    stats_small = compare(merl_small, native)  # type: ignore[arg-type]
    control = compare(other, native)  # type: ignore[arg-type]
    print(
        f"\n{name}: merl vs mitsuba {stats}\n{name}: merl rgb9e5 vs mitsuba {stats_small}"
        f"\n{name}: perturbed vs mitsuba {control}"
    )
    assert accepted(stats), stats
    assert accepted(stats_small), stats_small
    assert not accepted(control), control


def test02_bad_table_fails_naming_the_ref(settings: Settings) -> None:
    store = ArtifactStore(settings.store_dir)
    jobs = JobStore(settings.db_path)
    try:
        # A valid header and too few values: the store takes any bytes, the job must not.
        info = store.put_bytes(struct.pack("<3i", 90, 90, 180) + b"not a table")
        jobs.record_upload(info.digest, "broken.binary", MEDIA_TYPE, info.size)
    finally:
        jobs.close()
    ref = f"sha256:{info.digest}"
    params = {"material": {"merl": ref}, "resolution": [16, 16], "spp": 1}
    job = run_in_process({"kind": "render", "seed": 0, "params": params}, settings)
    assert job.state == "failed"
    assert job.error is not None and job.error.startswith(f"material.merl: {ref}: ")
    assert "size mismatch" in job.error


def test02b_rgb9e5_refuses_bins_missing_in_some_channels(
    settings: Settings, tmp_path: Path
) -> None:
    """A valid table with one bin missing in one channel only cannot be held as rgb9e5
    (one word per bin): the job fails with one line naming the key and the reference."""
    rgb = np.full((90, 90, 180, 3), 0.1)
    rgb[10, 20, 30, 1] = -1.0
    path = tmp_path / "partial.binary"
    write_merl(path, MerlTable(rgb))
    jobs = JobStore(settings.db_path)
    try:
        record = import_file(path, jobs, ArtifactStore(settings.store_dir))
    finally:
        jobs.close()
    ref = f"sha256:{record.digest}"
    material = {"merl": ref, "table_precision": "rgb9e5"}
    params = {"material": material, "resolution": [16, 16], "spp": 1}
    job = run_in_process({"kind": "render", "seed": 0, "params": params}, settings)
    assert job.state == "failed"
    assert job.error is not None and "\n" not in job.error
    assert job.error.startswith(f"material.table_precision: {ref}: ")
    assert "missing in some channels only" in job.error


def test03_spec_time_errors(settings: Settings) -> None:
    from jobapi.errors import SpecError

    with pytest.raises(SpecError, match="merl: must be an artifact reference"):
        run_in_process(
            {"kind": "render", "params": {"material": {"merl": "gold.binary"}}}, settings
        )
    with pytest.raises(SpecError, match="table_precision"):
        material = {"merl": "sha256:" + "0" * 64, "table_precision": "float8"}
        run_in_process({"kind": "render", "params": {"material": material}}, settings)
    missing = "sha256:" + "0" * 64
    with pytest.raises(SpecError, match="no such object in the store"):
        run_in_process({"kind": "render", "params": {"material": {"merl": missing}}}, settings)
