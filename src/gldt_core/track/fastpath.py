"""How the trackers evaluate a formula: on numpy arrays, or on Python floats for a few items.

Every formula of the trackers (IoU, the box conversions, JCMA's cost terms, the input check, ...)
is written once, as a function of its operands that uses Python's arithmetic and comparison
operators plus the few operations of an :class:`Ops` namespace. The same function then runs on
either kind of operand:

* :data:`ARRAYS` (numpy ufuncs): one call covers every pair of a pool at once, with operands
  broadcast over tracks and detections. Each numpy call has a fixed overhead that dwarfs the
  arithmetic of a handful of pairs.
* :data:`FLOATS` (the same operations on Python floats): the formula runs once per item, so its
  cost grows with the number of items but starts near zero.

:func:`on_floats` is the one switch between them, and :data:`MAX_FLOAT_ITEMS` its one threshold.
``tests/core/test_track_small_pools.py`` sets the threshold so that every formula runs on floats,
then on arrays, and compares.

Both evaluations give the same numbers: ``+ - * /``, ``%``, comparisons, ``abs``, ``sqrt``,
``minimum`` and ``maximum`` are exact IEEE operations (or selections) on either side, and
:meth:`FloatOps.hypot` is ``abs(complex(x, y))``, which CPython computes with the C library's
``hypot``, the function numpy calls (``math.hypot`` is CPython's own algorithm and differs in the
last bit for some inputs). Two things may differ by an ulp, and the tests allow for it: ``atan2``,
where numpy may use its own SIMD kernel (AVX-512) instead of the C library's; and a sum over many
terms that the array path hands to a BLAS product (JCMA's relational term), whose kernels may fuse
and reorder. Transcendental functions without a bit-identical float twin (``exp``) are applied to
all items in one numpy call on either path.
"""

from __future__ import annotations

import math
from typing import Generic, Protocol, TypeVar

import numpy as np

#: The operand type of a formula: a Python float, or a numpy array of them.
V = TypeVar("V", float, np.ndarray)
#: A condition: a bool for float operands, a boolean array for array operands.
Mask = bool | np.ndarray

#: Up to this many items (pairs of a cost matrix, boxes, detection rows) a formula is evaluated
#: item by item on Python floats. The break-even point of the costliest formula (JCMA's cost: about
#: a hundred numpy calls, or one pass of Python arithmetic per pair) lies near it, and the cheap
#: formulas gain little either way around it.
MAX_FLOAT_ITEMS = 16


def on_floats(items: int) -> bool:
    """Whether a formula evaluated ``items`` times runs on Python floats (else on numpy arrays)."""
    return items <= MAX_FLOAT_ITEMS


class Ops(Protocol, Generic[V]):
    """The operations a formula needs besides Python's operators, for one operand type."""

    def minimum(self, a: V | float, b: V | float) -> V: ...

    def maximum(self, a: V | float, b: V | float) -> V: ...

    def where(self, condition: Mask, a: V | float, b: V | float) -> V: ...

    def hypot(self, x: V, y: V) -> V: ...

    def atan2(self, y: V, x: V) -> V: ...

    def sqrt(self, x: V) -> V: ...


class FloatOps:
    """:class:`Ops` on Python floats. ``minimum``/``maximum`` select as numpy's do for numbers
    (conditional expressions: a fraction of the cost of the ``min``/``max`` builtins)."""

    @staticmethod
    def minimum(a: float, b: float) -> float:
        return a if a < b else b

    @staticmethod
    def maximum(a: float, b: float) -> float:
        return a if a >= b else b

    @staticmethod
    def where(condition: Mask, a: float, b: float) -> float:
        return a if condition else b

    @staticmethod
    def hypot(x: float, y: float) -> float:
        return abs(complex(x, y))  # the C library's hypot, as numpy's (see the module docstring)

    @staticmethod
    def atan2(y: float, x: float) -> float:
        return math.atan2(y, x)

    @staticmethod
    def sqrt(x: float) -> float:
        return math.sqrt(x)


class ArrayOps:
    """:class:`Ops` on numpy arrays."""

    @staticmethod
    def minimum(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
        return np.minimum(a, b)

    @staticmethod
    def maximum(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
        return np.maximum(a, b)

    @staticmethod
    def where(condition: Mask, a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
        return np.where(condition, a, b)

    @staticmethod
    def hypot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.hypot(x, y)

    @staticmethod
    def atan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
        return np.arctan2(y, x)

    @staticmethod
    def sqrt(x: np.ndarray) -> np.ndarray:
        return np.sqrt(x)


#: The namespaces are the classes themselves: a static method looked up on a class is a cheaper call
#: than one looked up on an instance, and the float path makes many.
FLOATS: Ops[float] = FloatOps
ARRAYS: Ops[np.ndarray] = ArrayOps
