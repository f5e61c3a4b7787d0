"""pycma (``cma``, the ``baselines`` extra), imported without the modules it loads for features no search here uses."""
from __future__ import annotations

import sys
import warnings

#: What pycma's own import pulls in for features no search here uses: ``scipy.stats`` (the rank correlation of its
#: surrogate models) and ``matplotlib`` (its plots). pycma treats both as optional (it catches their ImportError);
#: together they are most of its import's CPU time (about 1.3 of 1.4 s against 0.1 s without them).
PYCMA_OPTIONAL = ("scipy.stats", "matplotlib")


def import_cma():
    """The ``cma`` module, imported without :data:`PYCMA_OPTIONAL` where this process has not imported them.

    While ``cma`` is imported, those modules read as absent (``sys.modules[name] = None``); afterwards they are
    importable again as ever. A module already imported stays as it is (pycma then sees it, as a plain import
    would). The searches are the same either way: the options of :func:`sdm.experiments.baselines.cmaes.cmaes_search` use neither.
    """
    if "cma" in sys.modules:
        return sys.modules["cma"]
    hidden = [name for name in PYCMA_OPTIONAL if name not in sys.modules]
    for name in hidden:
        sys.modules[name] = None
    try:
        with warnings.catch_warnings():  # its notice that cma.plot() is not available: no search plots
            warnings.filterwarnings("ignore", message="Could not import matplotlib", category=UserWarning)
            import cma
    finally:
        for name in hidden:
            if name in sys.modules and sys.modules[name] is None:
                del sys.modules[name]
    return cma
