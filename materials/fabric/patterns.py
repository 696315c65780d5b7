"""Weave patterns as data: which yarn lies on top in each cell of a repeating tile.

Chen, Wang & Wang 2024 ("Real-time Neural Woven Fabric Rendering"), Sec. 5.1, trains on seven
patterns: plain, twill 3x3, 5x5 and 8x8, satin 5x5, 8x8 and 5x10; Fig. 5 tests an unseen
twill 4x4. All eight are built in (:data:`PATTERNS`); users add their own through
:func:`pattern_registry` or :func:`pattern_from_spec`, which validate them.

Conventions
-----------
A pattern is a boolean matrix ``warp_up`` of shape ``(R, C)``: ``warp_up[i, j]`` is True when
warp yarn ``j`` lies over weft yarn ``i`` at their crossing (the warp is visible there),
False when the weft is on top.

- Tile space: ``(s, t)`` in ``[0, 1)^2``, periodic. Column ``j`` covers
  ``s in [j / C, (j + 1) / C)``, row ``i`` covers ``t in [i / R, (i + 1) / R)``: row 0 is at
  ``t = 0`` (the bottom), so a matrix printed top-down shows the tile upside down.
- Warp yarns run along ``+t`` (the tile's y axis), weft yarns along ``+s`` (x).
- Physical size: a cell is ``cell_size = (width, height)`` in physical units (default
  ``(1, 1)``; the unit is the width of one warp cell). The tile is ``C * width`` by
  ``R * height``. Heights and visibility marching (``yarn.py``, ``integrand.py``) use these
  units; footprints are given in tile units.
- A *float* is a maximal run of consecutive cells (cyclically) where the same yarn stays on
  top: along a column for a warp, along a row for a weft. The yarn geometry curves over
  each float (Jin et al. 2022), so :meth:`Pattern.float_tables` precomputes, per cell, the
  float's length and the cell's offset from the float's start.

Choices where the paper is silent (listed in the report):

- Twill ``n x n`` is the ``k``-up, ``(n - k)``-down twill whose up-run shifts by one column
  per row: 3x3 = 2/1, 4x4 = 2/2, 5x5 = 3/2, 8x8 = 4/4.
- Satin ``n x n`` is warp-faced (one weft-up cell per row) with move number ``m``
  (``gcd(n, m) = 1``): 5x5 uses m = 2, 8x8 uses m = 3.
- Satin 5x10 is the 5x5 satin on a tile twice as tall as wide (cells 1 x 2): weft yarns
  twice as wide as warp yarns, warp floats twice as long. Jin et al.'s own satin maps use
  such 10 x 5 / 5 x 10 tiles; the paper gives no matrix for it.
- Validation demands that every row and every column hold both a warp-up and a weft-up
  cell: each yarn interlaces at least once per tile, so every float is finite.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

_NAME = re.compile(r"^[a-z][a-z0-9_]{0,63}\Z")
_UP_CHARS = frozenset("1Xx#")
_DOWN_CHARS = frozenset("0.-")


@dataclass(frozen=True, eq=False)
class Pattern:
    """A weave pattern: the warp-up matrix of one repeating tile and its cell size.

    See the module docstring for the axes. Construct directly, or with :meth:`from_rows`.
    Instances are immutable (the matrix is stored read-only) and validated on creation.
    """

    name: str
    """Registry key: lower case, digits and ``_``, at most 64 characters."""
    warp_up: np.ndarray
    """``(R, C)`` bool; ``warp_up[i, j]``: warp ``j`` over weft ``i`` (row 0 at ``t = 0``)."""
    cell_size: tuple[float, float] = (1.0, 1.0)
    """Physical ``(width, height)`` of one cell; the unit is a warp cell's width."""
    description: str = ""
    """Free text, e.g. the weave's textbook name."""
    _tables: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _NAME.match(self.name):
            raise ValueError(
                f"pattern name must match {_NAME.pattern} (lower case, digits, _), "
                f"got {self.name!r}"
            )
        m = np.asarray(self.warp_up)
        if m.ndim != 2 or m.shape[0] < 2 or m.shape[1] < 2:
            raise ValueError(f"pattern {self.name!r}: warp_up must be 2-D, at least 2x2")
        if m.shape[0] > 64 or m.shape[1] > 64:
            raise ValueError(f"pattern {self.name!r}: at most 64x64 cells, got {m.shape}")
        if m.dtype != bool:
            if not np.all(np.isin(m, (0, 1))):
                raise ValueError(f"pattern {self.name!r}: warp_up must hold only 0/1 or bools")
            m = m.astype(bool)
        rows_ok = m.any(axis=1) & (~m).any(axis=1)
        cols_ok = m.any(axis=0) & (~m).any(axis=0)
        if not rows_ok.all():
            bad = np.flatnonzero(~rows_ok).tolist()
            raise ValueError(
                f"pattern {self.name!r}: rows {bad} never interlace (need both a warp-up and "
                f"a weft-up cell in every row)"
            )
        if not cols_ok.all():
            bad = np.flatnonzero(~cols_ok).tolist()
            raise ValueError(
                f"pattern {self.name!r}: columns {bad} never interlace (need both a warp-up "
                f"and a weft-up cell in every column)"
            )
        try:
            cw, ch = (float(v) for v in self.cell_size)
        except (TypeError, ValueError):
            raise ValueError(f"pattern {self.name!r}: cell_size must be two numbers") from None
        if not (math.isfinite(cw) and math.isfinite(ch) and 0.1 <= cw <= 10 and 0.1 <= ch <= 10):
            raise ValueError(f"pattern {self.name!r}: cell_size entries must be in [0.1, 10]")
        m = m.copy()
        m.setflags(write=False)
        object.__setattr__(self, "warp_up", m)
        object.__setattr__(self, "cell_size", (cw, ch))
        object.__setattr__(self, "_tables", _float_tables(m))

    @classmethod
    def from_rows(
        cls,
        name: str,
        rows: Sequence[str],
        *,
        cell_size: tuple[float, float] = (1.0, 1.0),
        description: str = "",
    ) -> Pattern:
        """Build a pattern from strings, one per weft row, ``rows[0]`` at ``t = 0``.

        ``1``, ``X`` or ``#`` marks a warp-up cell; ``0``, ``.`` or ``-`` a weft-up cell.
        Example: ``Pattern.from_rows("plain", ["10", "01"])``.
        """
        if isinstance(rows, str) or not rows:
            raise ValueError("rows must be a non-empty sequence of strings")
        widths = {len(r) for r in rows}
        if len(widths) != 1:
            raise ValueError(f"pattern {name!r}: rows have different lengths {sorted(widths)}")
        matrix = []
        for r in rows:
            bad = set(r) - _UP_CHARS - _DOWN_CHARS
            if bad:
                raise ValueError(f"pattern {name!r}: unknown characters {sorted(bad)} in {r!r}")
            matrix.append([c in _UP_CHARS for c in r])
        return cls(name, np.array(matrix, dtype=bool), cell_size, description)

    @property
    def shape(self) -> tuple[int, int]:
        """``(R, C)``: weft rows and warp columns per tile."""
        return int(self.warp_up.shape[0]), int(self.warp_up.shape[1])

    @property
    def tile_size(self) -> tuple[float, float]:
        """Physical ``(width, height)`` of the tile: ``(C * cell width, R * cell height)``."""
        r, c = self.shape
        return c * self.cell_size[0], r * self.cell_size[1]

    @property
    def warp_fraction(self) -> float:
        """Fraction of cells where the warp is on top (area fraction, cells are equal)."""
        return float(self.warp_up.mean())

    def float_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-cell float bookkeeping, two read-only ``(R, C)`` float64 arrays.

        ``offset[i, j]``: how many cells of the same float precede cell ``(i, j)`` along the
        top yarn (rows for a warp, columns for a weft); ``length[i, j]``: the float's length
        in cells. A warp float covering rows 3, 4, 0 of a 5-row tile gives offsets 0, 1, 2.
        """
        return self._tables

    def transposed(self, name: str) -> Pattern:
        """The same weave with warp and weft exchanged (matrix transposed and complemented)."""
        ch, cw = self.cell_size
        return Pattern(name, ~self.warp_up.T, (ch, cw), f"warp/weft swap of {self.name}")


def _runs(line: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets and lengths of cyclic runs of True in a 1-D bool array (False cells: 0, 0)."""
    n = len(line)
    offset = np.zeros(n)
    length = np.zeros(n)
    start = int(np.flatnonzero(~line)[0])  # a False cell exists (validated): runs are finite
    run: list[int] = []
    for step in range(1, n + 1):  # the last step lands on ``start`` again and closes the run
        idx = (start + step) % n
        if line[idx]:
            run.append(idx)
            continue
        for pos, cell in enumerate(run):
            offset[cell] = pos
            length[cell] = len(run)
        run = []
    return offset, length


def _float_tables(warp_up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r, c = warp_up.shape
    offset = np.zeros((r, c))
    length = np.zeros((r, c))
    for j in range(c):  # warp floats run along a column
        o, n = _runs(warp_up[:, j])
        offset[:, j] += o
        length[:, j] += n
    for i in range(r):  # weft floats run along a row
        o, n = _runs(~warp_up[i, :])
        offset[i, :] += o
        length[i, :] += n
    offset.setflags(write=False)
    length.setflags(write=False)
    return offset, length


def plain(name: str = "plain") -> Pattern:
    """Plain (tabby) weave: warp and weft alternate at every crossing."""
    return Pattern.from_rows(name, ["10", "01"], description="plain weave")


def twill(n: int, up: int, name: str | None = None) -> Pattern:
    """``up/(n - up)`` twill on an ``n x n`` tile: row ``i`` has warps ``i .. i + up - 1`` up."""
    if not (2 <= n <= 64 and 1 <= up < n):
        raise ValueError(f"twill needs 2 <= n <= 64 and 1 <= up < n, got n={n}, up={up}")
    j = np.arange(n)
    m = np.array([((j - i) % n) < up for i in range(n)])
    return Pattern(name or f"twill_{n}x{n}", m, description=f"{up}/{n - up} twill")


def satin(
    n: int, move: int, name: str | None = None, *, cell_size: tuple[float, float] = (1.0, 1.0)
) -> Pattern:
    """Warp-faced ``n``-harness satin: row ``i`` has its single weft-up cell at ``i * move``."""
    if not (5 <= n <= 64 and 1 < move < n - 1 and math.gcd(n, move) == 1):
        raise ValueError(
            f"satin needs n >= 5 and 1 < move < n - 1 coprime with n, got n={n}, move={move}"
        )
    m = np.ones((n, n), dtype=bool)
    for i in range(n):
        m[i, (i * move) % n] = False
    return Pattern(
        name or f"satin_{n}x{n}",
        m,
        cell_size,
        f"warp-faced {n}-harness satin, move {move}",
    )


def _builtin() -> dict[str, Pattern]:
    patterns = [
        plain(),
        twill(3, 2),
        twill(4, 2),
        twill(5, 3),
        twill(8, 4),
        satin(5, 2),
        satin(8, 3),
        satin(5, 2, "satin_5x10", cell_size=(1.0, 2.0)),
    ]
    return {p.name: p for p in patterns}


#: The built-in patterns, read-only. Add others with :func:`pattern_registry`.
PATTERNS: Mapping[str, Pattern] = MappingProxyType(_builtin())

#: The seven patterns of the paper's training set (Sec. 5.1).
TRAINING_PATTERNS: tuple[str, ...] = (
    "plain",
    "twill_3x3",
    "twill_5x5",
    "twill_8x8",
    "satin_5x5",
    "satin_8x8",
    "satin_5x10",
)

#: Built-in patterns the paper keeps out of training (Fig. 5: an unseen twill 4x4).
UNSEEN_PATTERNS: tuple[str, ...] = ("twill_4x4",)


def pattern_registry(extra: Iterable[Pattern] = ()) -> Mapping[str, Pattern]:
    """A new read-only registry: the built-ins plus validated user patterns.

    Raises ``ValueError`` when a user pattern reuses a built-in or another user name. The
    built-in :data:`PATTERNS` is never modified.
    """
    merged = dict(PATTERNS)
    for p in extra:
        if not isinstance(p, Pattern):
            raise ValueError(f"expected a Pattern, got {type(p).__name__}")
        if p.name in merged:
            raise ValueError(f"pattern name {p.name!r} is already registered")
        merged[p.name] = p
    return MappingProxyType(merged)


def get_pattern(name: str, registry: Mapping[str, Pattern] = PATTERNS) -> Pattern:
    """Look a pattern up by name; ``ValueError`` lists the known names when it is missing."""
    try:
        return registry[name]
    except KeyError:
        known = ", ".join(sorted(registry))
        raise ValueError(f"unknown pattern {name!r}; known: {known}") from None


def pattern_from_spec(spec: Mapping[str, Any]) -> Pattern:
    """Validate a user pattern given as plain data (e.g. from a JSON job spec).

    ``{"name": "basket_2x2", "rows": ["1100", "1100", "0011", "0011"],
    "cell_size": [1, 1], "description": "..."}``; ``cell_size`` and ``description`` are
    optional. Unknown keys are rejected.
    """
    allowed = {"name", "rows", "cell_size", "description"}
    unknown = set(spec) - allowed
    if unknown:
        raise ValueError(f"unknown pattern keys {sorted(unknown)}; allowed: {sorted(allowed)}")
    if "name" not in spec or "rows" not in spec:
        raise ValueError("a pattern spec needs 'name' and 'rows'")
    rows = spec["rows"]
    if isinstance(rows, str) or not all(isinstance(r, str) for r in rows):
        raise ValueError("'rows' must be a list of strings")
    cell = spec.get("cell_size", (1.0, 1.0))
    if isinstance(cell, str) or len(cell) != 2:
        raise ValueError("'cell_size' must be two numbers")
    return Pattern.from_rows(
        str(spec["name"]),
        list(rows),
        cell_size=(float(cell[0]), float(cell[1])),
        description=str(spec.get("description", "")),
    )
