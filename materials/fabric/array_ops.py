"""The few array operations where numpy and Dr.Jit differ, behind one small interface.

The fabric physics (``yarn.py``, ``shading.py``, ``integrand.py``) is written once, as
element-wise code over an :class:`ArrayOps` object, so that the numpy estimator and the Dr.Jit
LLVM kernel (``aggregate_drjit.py``) run the very same formulas (DESIGN.md: one
implementation per formula). Arithmetic operators (``+ - * /``, comparisons, ``&``, ``|``,
``~``) are used directly on the arrays; everything else goes through ``ops``.

Conventions: arrays are float32 (numpy) or ``Float`` (Dr.Jit), any shape that broadcasts
(numpy) or flat (Dr.Jit). 3-vectors are tuples ``(x, y, z)`` of such arrays (structure of
arrays), so Dr.Jit traces them as three registers and numpy works on contiguous planes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeAlias

import numpy as np
from scipy.special import erfinv as _erfinv

#: A backend array (numpy float32 / bool / int, or a Dr.Jit array).
Array: TypeAlias = Any
#: A 3-vector as three backend arrays.
Vec3: TypeAlias = tuple[Any, Any, Any]


class ArrayOps(Protocol):
    """Element-wise operations the fabric physics needs from a backend."""

    name: str

    def sqrt(self, x: Array) -> Array:
        """Square root, clamped to 0 for tiny negative round-off."""
        ...

    def sin(self, x: Array) -> Array: ...

    def cos(self, x: Array) -> Array: ...

    def exp(self, x: Array) -> Array: ...

    def log(self, x: Array) -> Array: ...

    def abs(self, x: Array) -> Array: ...

    def floor(self, x: Array) -> Array: ...

    def erfinv(self, x: Array) -> Array: ...

    def minimum(self, a: Array | float, b: Array | float) -> Array: ...

    def maximum(self, a: Array | float, b: Array | float) -> Array: ...

    def where(self, cond: Array, a: Array | float, b: Array | float) -> Array:
        """``a`` where ``cond`` else ``b``; Python floats become the backend's float type."""
        ...

    def index(self, x: Array) -> Array:
        """Integer index from a non-negative, already floored float array."""
        ...

    def gather(self, table: Array, idx: Array) -> Array:
        """``table[idx]`` for a table made by :meth:`table`."""
        ...

    def table(self, values: np.ndarray) -> Array:
        """Upload a small float table (e.g. per-cell pattern data) for :meth:`gather`."""
        ...

    def march(
        self,
        count: Array,
        max_steps: int,
        lanes: tuple[Array, ...],
        flag: Array,
        body: Callable[[Array, tuple[Array, ...]], tuple[Array, Array]],
    ) -> Array:
        """Per-element loop over step indices: ``hit, k = body(k, lanes)``, ``flag |= hit``,
        from ``k = 0`` while ``k < count``.

        ``count`` (float, >= 1, at most ``max_steps``) may differ per element; the body
        returns the element's next step index (float, greater than ``k``: ``k + 1`` for a
        plain march, more where a hierarchy proves the steps in between clear), so at most
        ``max_steps`` iterations run. An element stops as soon as its ``flag`` is True.
        ``lanes`` are the per-element inputs the body reads (broadcastable arrays); the body
        must read per-element data only through them and ``k``, so numpy can run it on the
        still-active elements alone.
        """
        ...

    def march_many(
        self,
        counts: Sequence[Array],
        max_steps: int,
        lanes: Sequence[tuple[Array, ...]],
        body: Callable[[Array, tuple[Array, ...]], tuple[Array, Array]],
    ) -> list[Array]:
        """Several marches per element, ``march(counts[j], max_steps, lanes[j], False, body)``
        for each ``j``: the hit flags, one array per march.

        The same results as separate :meth:`march` calls; a SIMD backend runs them one after
        the other in a single loop, so a packet costs the slowest lane's *total* iterations
        instead of the sum of each march's slowest lane.
        """
        ...


class NumpyOps:
    """:class:`ArrayOps` over numpy arrays, computing in float32."""

    name = "numpy"

    def sqrt(self, x: Array) -> Array:
        return np.sqrt(np.maximum(x, np.float32(0.0)))

    def sin(self, x: Array) -> Array:
        return np.sin(x)

    def cos(self, x: Array) -> Array:
        return np.cos(x)

    def exp(self, x: Array) -> Array:
        return np.exp(x)

    def log(self, x: Array) -> Array:
        return np.log(x)

    def abs(self, x: Array) -> Array:
        return np.abs(x)

    def floor(self, x: Array) -> Array:
        return np.floor(x)

    def erfinv(self, x: Array) -> Array:
        return _erfinv(x).astype(np.float32, copy=False)

    def minimum(self, a: Array | float, b: Array | float) -> Array:
        return np.minimum(_f32(a), _f32(b))

    def maximum(self, a: Array | float, b: Array | float) -> Array:
        return np.maximum(_f32(a), _f32(b))

    def where(self, cond: Array, a: Array | float, b: Array | float) -> Array:
        return np.where(cond, _f32(a), _f32(b))

    def index(self, x: Array) -> Array:
        return np.asarray(x).astype(np.intp)

    def gather(self, table: Array, idx: Array) -> Array:
        return table[idx]

    def table(self, values: np.ndarray) -> Array:
        return np.ascontiguousarray(values, dtype=np.float32)

    def march(
        self,
        count: Array,
        max_steps: int,
        lanes: tuple[Array, ...],
        flag: Array,
        body: Callable[[Array, tuple[Array, ...]], tuple[Array, Array]],
    ) -> Array:
        # Compaction: each step evaluates the body on the elements still marching only.
        shape = np.broadcast_shapes(np.shape(count), np.shape(flag), *(np.shape(a) for a in lanes))
        flat = [np.broadcast_to(a, shape).ravel() for a in (count, *lanes)]
        out = np.array(np.broadcast_to(flag, shape)).ravel()
        k = np.zeros(out.shape, dtype=np.float32)
        live = np.flatnonzero(~out)
        for _ in range(max_steps):
            live = live[flat[0][live] > k[live]]
            if live.size == 0:
                break
            hit, k_next = body(k[live], tuple(a[live] for a in flat[1:]))
            out[live] = hit
            k[live] = k_next
            live = live[~hit]
        return out.reshape(shape)

    def march_many(
        self,
        counts: Sequence[Array],
        max_steps: int,
        lanes: Sequence[tuple[Array, ...]],
        body: Callable[[Array, tuple[Array, ...]], tuple[Array, Array]],
    ) -> list[Array]:
        # Compaction already keeps finished elements out of the work: march one by one.
        no = np.zeros((), dtype=bool)
        return [
            self.march(c, max_steps, lane, no, body) for c, lane in zip(counts, lanes, strict=True)
        ]


def _f32(x: Array | float) -> Array:
    """Python scalars become float32 so that numpy never promotes to float64."""
    return np.float32(x) if isinstance(x, int | float) else x


def dot(a: Vec3, b: Vec3) -> Array:
    """Component-wise dot product of two 3-vectors."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def normalize(ops: ArrayOps, v: Vec3, eps: float = 1e-12) -> tuple[Vec3, Array]:
    """``(v / |v|, |v|)``; where ``|v| <= eps`` the result is ``v / eps`` (callers mask it)."""
    length = ops.sqrt(dot(v, v))
    inv = 1.0 / ops.maximum(length, eps)
    return (v[0] * inv, v[1] * inv, v[2] * inv), length
