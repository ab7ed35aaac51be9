"""``linear_sum_assignment`` without importing all of ``scipy.optimize``.

The trackers need one function of SciPy: the rectangular linear assignment solver (the C extension
``scipy.optimize._lsap``). Importing it the normal way runs ``scipy.optimize/__init__``, which pulls
in ``scipy.linalg``, ``scipy.sparse`` and the whole optimiser collection: 0.5 s on an idle 2-core
machine and 2.5 s while other processes start beside it. That import sat on the critical path of
the tracker node's start-up and of its restart after a crash (issues #8 and #9: first track within
5 s, tracks again within 2 s of a restart; ``tests/test_ros_faults.py`` measures the latter from
the moment the supervisor restarts the node).

So the extension is loaded directly from its file under the installed ``scipy`` package, without
executing the package ``__init__`` files. It is the same compiled solver, so results are identical
(``tests/test_track_api.py`` checks it against ``scipy.optimize.linear_sum_assignment``). When that
is not possible (another SciPy layout), the normal import is used: slower to start, same answer.
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
        solver = _load_extension_directly()
    except (ImportError, OSError):
        solver = None
    if solver is not None:
        return solver, "extension"
    from scipy.optimize import linear_sum_assignment as solver

    return solver, "scipy.optimize"


_SOLVER, SOURCE = _resolve()


def linear_sum_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-cost assignment of a 2-D cost matrix: ``(row indices, column indices)``, as SciPy's."""
    return _SOLVER(np.asarray(cost, dtype=np.float64))
