"""Bonn ``.btf`` files (UBO2014's DFMF, and FMF): our reader against our writer, against
closed forms and against numpy products computed here, and the refusals.

References: a Lambertian plane is ``albedo / pi * cos(theta_i)`` in our convention (closed
form); a factorised file decodes to ``U @ SxV.T`` (numpy, computed in the test from the
factors written, with the row flip and the cosine rule of the module docstring applied
here); btflib's YUV->RGB matrix is inverted by numpy to encode.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from storage.errors import FormatError, TooLargeError
from storage.formats import validate_file
from storage.formats.ubo_btf import UboBtf, read_header, sniff
from storage.formats.ubo_btf_write import encode_slices, factorize, write_dfmf, write_fmf

# Three lights and two views (theta, phi in radians), 4 x 4 texels.
LIGHTS = np.radians([[0.0, 0.0], [30.0, 45.0], [60.0, -120.0]])
VIEWS = np.radians([[11.0, 15.0], [45.0, 180.0]])
H = W = 4
COUNT = len(LIGHTS) * len(VIEWS)
THETA_I = np.tile(LIGHTS[:, 0], len(VIEWS))  # slice k = view * n_lights + light


def albedo() -> np.ndarray:
    """(H, W, 3) albedo in our orientation: a ramp in y (rows) to catch a flip."""
    y = np.arange(H)[:, None, None] / H
    x = np.arange(W)[None, :, None] / W
    return np.broadcast_to(0.2 + 0.5 * y + 0.1 * x * np.array([1.0, 0.5, 0.2]), (H, W, 3))


def lambert() -> np.ndarray:
    return albedo()[None] / math.pi * np.cos(THETA_I)[:, None, None, None]


def dfmf(path: Path, rgb: np.ndarray, *, model: int = 0, cosine: bool = True, scalar: int = 8,
         k: int | None = None) -> Path:  # fmt: skip
    mats = encode_slices(rgb, THETA_I, cosine_flag=cosine, color_model=model)
    return write_dfmf(path, lights=LIGHTS, views=VIEWS, width=W, height=H,
                      factors=[factorize(m, k) for m in mats], color_model=model,
                      cosine_flag=cosine, scalar=scalar)  # fmt: skip


def test01_header_and_directions(tmp_path: Path) -> None:
    p = dfmf(tmp_path / "a.btf", lambert())
    assert sniff(p)
    h = read_header(p)
    assert (h.variant, h.count, h.width, h.height) == ("DFMF", COUNT, W, H)
    a = h.angles_deg()
    # slice 4 = view 1, light 1
    np.testing.assert_allclose(a[4], [30.0, 45.0, 45.0, 180.0], atol=1e-4)


@pytest.mark.parametrize("model", [0, 1, 11])
@pytest.mark.parametrize("cosine", [True, False])
def test02_lambertian_plane_is_albedo_over_pi_cos(tmp_path: Path, model: int, cosine: bool) -> None:
    """Whatever colour model and cosine flag the file uses, decoding gives the closed form
    albedo / pi * cos(theta_i), rows in our orientation (row 0 at y = 0)."""
    p = dfmf(tmp_path / "l.btf", lambert(), model=model, cosine=cosine)
    out = UboBtf(p).decode(range(COUNT))
    assert out.shape == (COUNT, H, W, 3) and out.dtype == np.float32
    ref = albedo()[None] / math.pi * np.cos(THETA_I)[:, None, None, None]
    np.testing.assert_allclose(out, ref, rtol=1e-5, atol=1e-7)


def test03_rank_one_in_the_file_decodes_the_same(tmp_path: Path) -> None:
    """The Lambertian plane written as the rank-1 factors a measurement system would
    store (no cosine in the data, flag off): U = 1/pi per pair, SxV = albedo per texel in
    the file's top-down order; half-precision scalars."""
    top_down = albedo()[::-1].reshape(-1, 3)
    factors = [(np.full((COUNT, 1), 1 / math.pi), top_down[:, c : c + 1]) for c in range(3)]
    p = write_dfmf(tmp_path / "r1.btf", lights=LIGHTS, views=VIEWS, width=W, height=H,
                   factors=factors, cosine_flag=False, scalar=2)  # fmt: skip
    out = UboBtf(p).decode([5, 0])
    ref = lambert()[[5, 0]]
    np.testing.assert_allclose(out, ref, rtol=2e-3)  # half precision: 11-bit mantissa


def test04_random_factors_decode_to_the_numpy_product(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    factors = [(rng.uniform(0, 1, (COUNT, k)), rng.uniform(0, 1, (H * W, k))) for k in (3, 2, 1)]
    p = write_dfmf(tmp_path / "rnd.btf", lights=LIGHTS, views=VIEWS, width=W, height=H,
                   factors=factors, scalar=4)  # fmt: skip
    out = UboBtf(p).decode([3, 1])
    for j, k in enumerate([3, 1]):
        for c, (u, sxv) in enumerate(factors):
            u32, s32 = u.astype(np.float32).astype(np.float64), sxv.astype(np.float32)
            ref = (s32.astype(np.float64) @ u32[k]).reshape(H, W)[::-1]
            np.testing.assert_allclose(out[j, :, :, c], ref, rtol=1e-6)


def test05_fmf_round_trip_with_dynamic_range_reduction(tmp_path: Path) -> None:
    """FMF: one factorisation of all channels (row pair * 3 + channel), values stored as
    log(v + eps)."""
    rgb = lambert()
    logs = np.log(rgb[:, ::-1].reshape(COUNT, H * W, 3) + 1e-5)  # (pair, texel, channel)
    u, sxv = factorize(np.moveaxis(logs, 2, 1).reshape(COUNT * 3, H * W))
    p = write_fmf(tmp_path / "f.btf", lights=LIGHTS, views=VIEWS, width=W, height=H,
                  u=u, sxv=sxv, drr=True, scalar=8)  # fmt: skip
    assert read_header(p).variant == "FMF"
    np.testing.assert_allclose(UboBtf(p).decode(range(COUNT)), rgb, rtol=1e-5)


def test06_validate_file_accepts_and_caps(tmp_path: Path) -> None:
    p = dfmf(tmp_path / "ok.btf", lambert())
    assert validate_file(p, "ok.btf") == "application/x-ubo-btf"
    with pytest.raises(TooLargeError, match="ok.btf: 6 slices of 4x4 decode to 96 pixels"):
        validate_file(p, "ok.btf", max_archive_pixels=95)


def _refused(tmp_path: Path) -> list[tuple[bytes, str]]:
    good = dfmf(tmp_path / "g.btf", lambert()).read_bytes()
    meta_size = struct.unpack("<I", good[10:14])[0]
    huge_xml = bytearray(good)
    # the XML length field sits after size, version, 240 chars, ppmm, RGB scale, cosine flag
    struct.pack_into("<I", huge_xml, 10 + 4 + 4 + 240 + 4 + 12 + 4, 1 << 30)
    bad_size = bytearray(good)
    struct.pack_into("<I", bad_size, 10, meta_size + 4)
    four = bytearray(good)
    struct.pack_into("<I", four, 10 + 4 + 4 + 240 + 4 + 12 + 4 + 4, 4)  # after XML length 0
    many_views = bytearray(good)
    struct.pack_into("<I", many_views, 10 + meta_size, 1 << 30)
    return [
        (good[:-7], r"g\.btf: truncated: channel 2 SxV"),
        (good[: 10 + meta_size + 10], r"g\.btf: truncated: view 0"),
        (good + b"\0\0", r"g\.btf: 2 bytes after the last matrix"),
        (b"!DFMX" + good[5:], r"g\.btf: not a Bonn BTF"),
        (b"!BDIF06R2!" + good[10:], r"variant BDI .* does not decode"),
        (bytes(huge_xml), r"XML length is 1073741824, outside"),
        (bytes(bad_size), r"meta block says"),
        (bytes(many_views), r"view count is 1073741824, outside"),
        (bytes(four), r"4 colour channels; only 3-channel"),
    ]


def test07_malformed_files_are_refused_naming_the_file(tmp_path: Path) -> None:
    for k, (data, pattern) in enumerate(_refused(tmp_path)):
        p = tmp_path / f"bad{k}.btf"
        p.write_bytes(data)
        with pytest.raises(FormatError, match=pattern.replace("g\\.btf", "g.btf")):
            read_header(p, "g.btf")
        with pytest.raises(FormatError):
            validate_file(p, f"bad{k}.btf")


def test08_unsupported_colour_model_is_named(tmp_path: Path) -> None:
    factors = [(np.ones((COUNT, 1)), np.ones((H * W, 1)))] * 3
    p = write_dfmf(tmp_path / "lab.btf", lights=LIGHTS, views=VIEWS, width=W, height=H,
                   factors=factors, color_model=2)  # fmt: skip
    with pytest.raises(FormatError, match=r"lab\.btf: DFMF colour model 2 \(Lab\)"):
        read_header(p)


def test09_cosine_override(tmp_path: Path) -> None:
    """A file whose flag says the cosine is in the data, read as if it were not: each
    slice is multiplied by cos(theta_i) once more (closed form: lambert * cos)."""
    p = dfmf(tmp_path / "c.btf", lambert(), cosine=True)
    out = UboBtf(p).decode(range(COUNT), cosine_in_data=False)
    ref = lambert() * np.cos(THETA_I)[:, None, None, None]
    np.testing.assert_allclose(out, ref, rtol=1e-5, atol=1e-7)
