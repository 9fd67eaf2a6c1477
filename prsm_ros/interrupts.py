"""A Ctrl-C a command has handled exits with the status the command chose.

CPython notes a KeyboardInterrupt that leaves code it runs from source text (`exec` of a string, which
numba's compilation, `dataclasses` and some of scipy's imports do) in a process-wide flag, and does so
even when an `except KeyboardInterrupt` further out handles it. A process started as `python -m` whose
flag is set kills itself with SIGINT at exit, after finalising (CPython's main, the "uncaught ^C" exit of
bpo-1054041): the 130 a command returned after saying what it kept reaches its parent as death by SIGINT
(-2). Measured on `python -m prsm_ros.fit.cli`, interrupted right after its fit started: 2 of 10 runs
exited -2, the flag set in both; none once the flag was cleared where the interrupt is handled.
"""

from __future__ import annotations


def interrupt_handled() -> None:
    """Call where a KeyboardInterrupt is handled: clears CPython's record of an unhandled one (module doc).

    A no-op where the interpreter keeps no such record (another implementation or version)."""
    try:
        import ctypes
        ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt").value = 0
    except (AttributeError, ValueError, OSError):  # no such symbol here
        pass
