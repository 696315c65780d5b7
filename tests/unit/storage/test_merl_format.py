"""The MERL ``.binary`` reader and writer.

Oracle: the layout of MERL's reference ``BRDFRead.cpp`` (three int32 dims, then float64 R,
G, B planes in (theta_h, theta_d, phi_d) order, ``physical = stored * scale`` with scales
1/1500, 1.15/1500, 1.66/1500), written here byte by byte with ``struct`` rather than with
our writer.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from storage.errors import FormatError
from storage.formats.merl import (
    MerlTable,
    merl_bytes,
    merl_from_bytes,
    read_merl,
    validate_merl,
    write_merl,
)

N180 = 90 * 90 * 180


def sample_table(phi_d_bins: int = 180, seed: int = 0) -> MerlTable:
    rng = np.random.default_rng(seed)
    rgb = rng.lognormal(-2.0, 2.0, size=(90, 90, phi_d_bins, 3))
    rgb[80:, 85:] = -1.0  # missing block
    return MerlTable(rgb=rgb, phi_d_bins=phi_d_bins)


def reference_file(stored: np.ndarray, dims: tuple[int, int, int]) -> bytes:
    """Bytes as the reference reader expects them, built without our writer."""
    return struct.pack("<iii", *dims) + stored.astype("<f8").tobytes()


def test01_header_and_scales(tmp_path: Path) -> None:
    table = sample_table()
    data = merl_bytes(table)
    assert struct.unpack("<iii", data[:12]) == (90, 90, 180)
    assert len(data) == 12 + 3 * N180 * 8
    stored = np.frombuffer(data[12:], dtype="<f8").reshape(3, 90, 90, 180)
    # The reference lookup multiplies stored values by the scales to get physical ones.
    for c, scale in enumerate((1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)):
        np.testing.assert_allclose(stored[c] * scale, table.rgb[..., c], rtol=1e-15)
    # Index order: phi_d fastest, then theta_d, then theta_h.
    ih, id_, ip = 7, 33, 101
    ind = ip + id_ * 180 + ih * 180 * 90
    flat = np.frombuffer(data[12:], dtype="<f8")
    assert flat[ind] * (1.0 / 1500.0) == pytest.approx(table.rgb[ih, id_, ip, 0], rel=1e-15)
    assert flat[ind + 2 * N180] * (1.66 / 1500.0) == pytest.approx(
        table.rgb[ih, id_, ip, 2], rel=1e-15
    )


def test02_reads_reference_layout(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    stored = rng.uniform(0.0, 3000.0, size=3 * N180)
    stored[:10] = -1.0
    path = tmp_path / "ref.binary"
    path.write_bytes(reference_file(stored, (90, 90, 180)))
    table = read_merl(path)
    planes = stored.reshape(3, 90, 90, 180)
    np.testing.assert_array_equal(table.rgb[..., 0], planes[0] * (1.0 / 1500.0))
    np.testing.assert_array_equal(table.rgb[..., 1], planes[1] * (1.15 / 1500.0))
    np.testing.assert_array_equal(table.rgb[..., 2], planes[2] * (1.66 / 1500.0))
    assert table.missing[0, 0, :10].all() and not table.missing[0, 0, 10]


def test03_round_trip(tmp_path: Path) -> None:
    table = sample_table()
    path = tmp_path / "t.binary"
    write_merl(path, table)
    back = read_merl(path)
    assert back.phi_d_bins == 180
    # A division by the scale on write, a multiplication on read: two correctly rounded
    # float64 operations, 2.2e-16 each (measured 2e-16), the same on any IEEE machine.
    np.testing.assert_allclose(back.rgb, table.rgb, rtol=5e-16, atol=0)
    assert np.array_equal(back.missing, table.missing)
    # Deterministic bytes; re-encoding what was read changes stored values by <= 1 ulp.
    assert merl_bytes(table) == merl_bytes(sample_table())
    again = merl_bytes(merl_from_bytes(path.read_bytes()))
    assert again[:12] == path.read_bytes()[:12]
    np.testing.assert_allclose(
        np.frombuffer(again[12:], "<f8"), np.frombuffer(path.read_bytes()[12:], "<f8"), rtol=5e-16
    )
    validate_merl(path)


def test04_accepts_360_variant(tmp_path: Path) -> None:
    table = sample_table(360)
    path = tmp_path / "t360.binary"
    write_merl(path, table)
    assert path.stat().st_size == 12 + 3 * 2 * N180 * 8
    back = read_merl(path)
    assert back.phi_d_bins == 360
    np.testing.assert_allclose(back.rgb, table.rgb, rtol=5e-16)


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (b"", "shorter than the 12-byte header"),
        (b"\x5a\x00\x00\x00\x5a\x00", "shorter than the 12-byte header"),
        (
            struct.pack("<iii", 90, 90, 90) + bytes(8 * 3 * 90 * 90 * 90),
            r"dimensions \(90, 90, 90\)",
        ),
        (struct.pack("<iii", 180, 90, 90) + bytes(8 * 3 * N180), "dimensions"),
        (
            struct.pack("<iii", 90, 90, 180) + bytes(100),
            f"expected {12 + 24 * N180} bytes, got 112",
        ),
    ],
)
def test05_refuses_malformed(tmp_path: Path, data: bytes, match: str) -> None:
    path = tmp_path / "bad.binary"
    path.write_bytes(data)
    with pytest.raises(FormatError, match=match) as err:
        read_merl(path)
    assert str(path) in str(err.value)
    with pytest.raises(FormatError, match="upload.binary"):
        validate_merl(path, "upload.binary")


def test06_refuses_truncated_extra_and_nonfinite(tmp_path: Path) -> None:
    good = merl_bytes(sample_table())
    path = tmp_path / "x.binary"
    path.write_bytes(good[:-8])
    with pytest.raises(FormatError, match=f"expected {len(good)} bytes, got {len(good) - 8}"):
        read_merl(path)
    path.write_bytes(good + b"\x00" * 8)
    with pytest.raises(FormatError, match=f"got {len(good) + 8}"):
        read_merl(path)
    for bad in (np.nan, np.inf):
        corrupt = bytearray(good)
        corrupt[12 + 8 * (N180 + 5) : 12 + 8 * (N180 + 6)] = struct.pack("<d", bad)
        path.write_bytes(bytes(corrupt))
        with pytest.raises(FormatError, match="non-finite.*G plane at entry 5") as err:
            read_merl(path)
        assert err.value.filename == str(path)


def test07_unreadable_and_table_checks(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="cannot read"):
        read_merl(tmp_path / "absent.binary")
    with pytest.raises(ValueError, match="shape"):
        MerlTable(rgb=np.zeros((90, 90, 180, 3)), phi_d_bins=360)
    with pytest.raises(ValueError, match="phi_d_bins"):
        MerlTable(rgb=np.zeros((90, 90, 90, 3)), phi_d_bins=90)
