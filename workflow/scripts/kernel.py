"""The notebook kernel of a stage: ``python -m ipykernel_launcher`` without the debugger.

    python workflow/scripts/kernel.py -f CONNECTION_FILE

:func:`run_notebook.kernel_manager` starts the kernel with this file in place of
``-m ipykernel_launcher``, everything else of the kernel spec (the Python, its
arguments, the environment) unchanged. The kernel is ipykernel's own, started as
ipykernel's launcher starts it; only its debugger is off. ipykernel loads debugpy
at start-up to offer the debugger, which a notebook run by papermill never uses,
and that import is the largest part of a kernel's start (about a third of its CPU
time): the kernel reports no "debugger" feature, and nothing else changes. A
notebook can still import debugpy itself.
"""
import sys

if __name__ == "__main__":
    # This file's folder leaves sys.path, as ipykernel's launcher removes the working directory (IPython puts
    # the working directory back): the notebook imports what a kernel started by Jupyter would import.
    del sys.path[0]
    # ipykernel decides once, when its debugger module is first imported, whether debugpy is there.
    sys.modules["debugpy"] = None
    import ipykernel.debugger  # noqa: F401, E402
    del sys.modules["debugpy"]

    from ipykernel import kernelapp  # noqa: E402

    kernelapp.launch_new_instance()
