"""One-to-one matching for the trackers: :func:`assign`, on SciPy's rectangular assignment solver.

The association stages (:mod:`gldt_core.track.base`), PMR recovery
(:mod:`gldt_core.track.jptrack`) and low-score birth (:mod:`gldt_core.track.birth`) all match with
:func:`assign`.

The trackers need one function of SciPy: the rectangular linear assignment solver (the C extension
``scipy.optimize._lsap``). Importing it the normal way runs ``scipy.optimize/__init__``, which pulls
in ``scipy.linalg``, ``scipy.sparse`` and the whole optimiser collection, and that import sat on the
critical path of the tracker node's start-up and of its restart after a crash (issues #8 and #9:
first track within 5 s, tracks again within 2 s of a restart; ``tests/faults/test_ros_faults.py``
measures the latter from the moment the supervisor restarts the node).

So the extension is loaded directly from its file under the installed ``scipy`` package, without
executing the package ``__init__`` files. It is the same compiled solver, so results are identical
(``tests/core/test_track_api.py`` checks it against ``scipy.optimize.linear_sum_assignment``). When
that is not possible (another SciPy layout), the normal import is used: slower to start, same answer.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

_MODULE = "scipy.optimize._lsap"


def _load_extension_directly() -> Callable | None:
    """The ``linear_sum_assignment`` of the ``_lsap`` extension file, or None if not found."""
    if _MODULE in sys.modules:
        return getattr(sys.modules[_MODULE], "linear_sum_assignment", None)
    spec = importlib.util.find_spec("scipy")  # locates the package without executing it
    if spec is None or not spec.submodule_search_locations:
        return None
    folder = Path(next(iter(spec.submodule_search_locations))) / "optimize"
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = folder / f"_lsap{suffix}"
        if path.is_file():
            loader = importlib.machinery.ExtensionFileLoader(_MODULE, str(path))
            module_spec = importlib.util.spec_from_file_location(_MODULE, path, loader=loader)
            if module_spec is None:
                return None
            module = importlib.util.module_from_spec(module_spec)
            loader.exec_module(module)
            return getattr(module, "linear_sum_assignment", None)
    return None


def _resolve() -> tuple[Callable, str]:
    try:
        direct = _load_extension_directly()
    except (ImportError, OSError):
        direct = None
    if direct is not None:
        return direct, "extension"
    from scipy.optimize import linear_sum_assignment as solver

    return solver, "scipy.optimize"


_SOLVER, SOURCE = _resolve()


def linear_sum_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-cost assignment of a 2-D cost matrix: ``(row indices, column indices)``, as SciPy's."""
    return _SOLVER(np.asarray(cost, dtype=np.float64))


def assign(cost: np.ndarray, allowed: np.ndarray, limit: float) -> list[tuple[int, int]]:
    """Minimum-cost one-to-one matching of ``allowed`` pairs, where leaving a row or a column
    unmatched costs ``limit / 2`` (``allowed`` pairs should cost at most ``limit``).

    This is what ByteTrack's reference ``lap.lapjv(cost, extend_cost=True, cost_limit=thresh)``
    solves. A plain assignment over the allowed pairs would instead match as many pairs as it can
    before it looks at cost: with two tracks side by side, one of them missed and a new object
    beside the other, it hands the present track the newcomer and the missed track the present
    track's detection, swapping their ids. Here keeping the good pair (cost c) and leaving the
    other two unmatched (limit) beats the swap whenever the swap costs more.

    How, without lapjv's doubled matrix: a matching of k pairs costs ``sum(c) + (n + m - 2k) *
    limit / 2``, that is ``sum(c - limit)`` plus a constant. So each allowed pair gets ``c - limit``
    (<= 0) and each forbidden one 0, and the rectangular solver's full assignment, minus its
    forbidden pairs, is the optimal matching: padding a matching with zero-cost pairs is free.
    A pair at exactly the limit gets a hair below 0, so it is matched rather than left to chance.
    """
    if cost.size == 0 or not allowed.any():
        return []
    gain = np.where(allowed, cost - (float(limit) + 1e-9), 0.0)
    rows, cols = linear_sum_assignment(gain)
    return [(int(r), int(c)) for r, c in zip(rows, cols) if allowed[r, c]]
