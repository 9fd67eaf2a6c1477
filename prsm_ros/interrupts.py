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


def import_native(*modules: str) -> None:
    """Import `modules` (fixed names the caller writes, never input) with a Ctrl-C held until they are loaded.

    A pybind11 extension whose initialisation a KeyboardInterrupt reaches turns it into
    `ImportError: initialization failed` (scipy's `_highspy`, seen once in an interrupted `prsm-fit`), so the
    command would end in a traceback instead of its interrupt handler. Here a SIGINT that arrives during the
    imports is noted and delivered, to the handler that was in place, once they are done. Python runs its signal
    handlers in the main thread only; elsewhere no interrupt can land in an import and the modules load as is.
    """
    import importlib
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        for name in modules:
            importlib.import_module(name)
        return
    held: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, _frame: held.append(signum))
    try:
        for name in modules:
            importlib.import_module(name)
    finally:
        signal.signal(signal.SIGINT, previous)
    if not held or previous == signal.SIG_IGN:
        return
    if callable(previous):
        previous(signal.SIGINT, None)
    else:  # the default action, or a handler installed outside Python: the signal again, now it can land
        signal.raise_signal(signal.SIGINT)
