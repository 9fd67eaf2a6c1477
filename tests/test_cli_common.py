"""What every command-line tool does alike: `--version`, and Ctrl-C on a long command (a message
saying what was kept, exit 130, no traceback).

Oracle: the installed console scripts (pyproject's [project.scripts]) and the package version;
for Ctrl-C, a real SIGINT into a running `prsm-sim run`, and KeyboardInterrupt raised where the
other commands spend their time.
"""

from __future__ import annotations

import os
import signal
import subprocess
import re
import sys
from pathlib import Path

import pytest

from prsm_sim import __version__

ROOT = Path(__file__).resolve().parent.parent
# [project.scripts] of pyproject.toml, read as text (tomllib is Python 3.11+; the package runs on 3.10)
_SECTION = (ROOT / "pyproject.toml").read_text(encoding="utf-8").split("[project.scripts]\n", 1)[1].split("\n[", 1)[0]
SCRIPTS = dict(re.findall(r'^([\w-]+) = "([\w.:]+)"', _SECTION, re.M))


def test_the_scripts_are_read():
    assert {"prsm-sim", "prsm-node", "prsm-fmu", "prsm-ctl"} <= set(SCRIPTS), SCRIPTS


@pytest.mark.parametrize("command", sorted(SCRIPTS))
def test_every_command_has_version(command):
    module = SCRIPTS[command].split(":")[0]
    r = subprocess.run([sys.executable, "-m", module, "--version"], capture_output=True, text=True, timeout=120,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"{command} {__version__}", (r.stdout, r.stderr)


@pytest.mark.slow
def test_ctrl_c_in_prsm_sim_run_says_what_was_kept_and_exits_130(tmp_path):
    """A long run interrupted while it steps: one line saying nothing was written, exit 130."""
    csv = tmp_path / "run.csv"
    p = subprocess.Popen([sys.executable, "-m", "prsm_ros.cli.sim", "run", "--model", "ideal", "--duration", "2000",
                          "--csv", str(csv)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        seen = ""
        while "step" not in seen:  # the progress bar is up: the run is stepping
            ch = p.stderr.read(1)
            assert ch, "prsm-sim run ended before showing progress"
            seen += ch
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, err
    assert "prsm-sim: interrupted at step" in err and "nothing written" in err
    assert "Traceback" not in err and not csv.exists()


def test_ctrl_c_in_prsm_bench_prints_the_areas_measured_and_exits_130(capsys):
    from prsm_ros.bench.common import figure, main

    def measured(quick):
        return [figure("a figure", 1.0, "s", "≤ 2", True)]

    def interrupted(quick):
        raise KeyboardInterrupt

    assert main({"first": measured, "second": interrupted, "third": measured}, ["--json"]) == 130
    out, err = capsys.readouterr()
    assert "prsm-bench: interrupted: 1 of 3 areas measured (first)" in err
    assert '"area": "first"' in out and '"interrupted": true' in out and "third" not in out


def test_ctrl_c_in_prsm_demo_stops_the_node_so_it_closes_its_bag_and_exits_130(tmp_path, monkeypatch, capsys):
    """The node is stopped with SIGINT (it closes its bag then); the demo names the bag and exits 130."""
    from prsm_ros.cli import demo
    bag = tmp_path / "run.mcap"
    stopped = tmp_path / "node-stopped"
    # SIGINT blocked before the bag tells the test the node is up, then taken with sigtimedwait: the
    # stand-in neither dies of a SIGINT that comes early nor depends on a handler interrupting a sleep
    node_code = ("import signal, pathlib\n"
                 "signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT])\n"
                 f"pathlib.Path({str(bag)!r}).write_bytes(b'bag')\n"
                 "got = signal.sigtimedwait([signal.SIGINT], 600)\n"
                 f"pathlib.Path({str(stopped)!r}).write_text(repr(got and got.si_signo))\n")

    def start_module(module, args, env, **kw):
        code = node_code if module == "prsm_ros.cli.node" else "import time; time.sleep(600)"
        return subprocess.Popen([sys.executable, "-c", code], env={**os.environ, **env}, **kw)

    def ctrl_c(ctl, node):
        while not bag.exists():  # the node is up
            if node.poll() is not None:
                raise AssertionError("the stand-in node died")
        raise KeyboardInterrupt

    stop, node_rc = demo._stop, []
    monkeypatch.setattr(demo, "start_module", start_module)
    monkeypatch.setattr(demo, "wait_for_controller", ctrl_c)
    monkeypatch.setattr(demo, "_stop", lambda node: node_rc.append(stop(node)) or node_rc[-1])
    assert demo.main(["--record", str(bag), "--domain-id", "7"]) == 130
    err = capsys.readouterr().err
    assert f"prsm-demo: interrupted: the bag so far is in {bag}" in err
    assert node_rc == [0] and stopped.read_text() == str(int(signal.SIGINT)), \
        f"the node was not stopped with SIGINT: exit code {node_rc}, it took {stopped.exists() and stopped.read_text()}"


DEPRECATED = {"prsm_ros.cli.json_out": "prsm_ros.json_out", "prsm_ros.cli.param_files": "prsm_ros.param_files"}


@pytest.mark.parametrize("module", sorted(DEPRECATED))
def test_compatibility_modules_warn_and_nothing_in_the_project_imports_them(module, monkeypatch):
    """The old homes of the JSON and parameter-file helpers still work for users, warn with the
    version that removes them (CHANGES.md says the same), and no module of the project uses them."""
    import ast
    import importlib
    monkeypatch.delitem(sys.modules, module, raising=False)
    with pytest.warns(DeprecationWarning, match=f"{module} is deprecated and is removed in prsm 0.2.0"):
        mod = importlib.import_module(module)
    new = importlib.import_module(DEPRECATED[module])
    assert all(getattr(mod, n) is getattr(new, n) for n in mod.__all__)
    assert f"`{module}`" in (ROOT / "CHANGES.md").read_text(encoding="utf-8").split("\n## ")[1]
    users = []
    for path in sorted([*(ROOT / "prsm_sim").rglob("*.py"), *(ROOT / "prsm_ros").rglob("*.py")]):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
                     if isinstance(node, ast.ImportFrom) else [])
            if module in names:
                users.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not users, f"{module} is imported by {users}; import {DEPRECATED[module]}"


def test_the_demo_controller_shows_the_simulated_time_as_the_run_goes(capsys):
    """prsm-demo's progress: the controller rewrites one stderr line every quarter simulated second."""
    from prsm_ros.cli.demo_controller import PROGRESS_EVERY_S, show_progress
    st = {"shown": -1.0}
    for k in range(2001):  # 2 s at 1 ms
        show_progress(st, k * 1e-3, 2.0)
    err = capsys.readouterr().err
    updates = err.split("\r")[1:]
    assert len(updates) == round(2.0 / PROGRESS_EVERY_S) + 1
    assert updates[0] == "prsm-demo: 0.00 of 2 s simulated" and updates[-1] == "prsm-demo: 2.00 of 2 s simulated\n"


_EXEC_INTERRUPTED = '''
import sys
def main(handled):
    try:  # source text run by exec, as numba's compilation and dataclasses run theirs
        exec("import sys, time\\nprint('ready', flush=True)\\nwhile True: time.sleep(0.001)\\n")
    except KeyboardInterrupt:
        if handled:
            from prsm_ros.interrupts import interrupt_handled
            interrupt_handled()
        print("interrupted", file=sys.stderr)
        return 130
if __name__ == "__main__":
    sys.exit(main(sys.argv[1] == "handled"))
'''


def test_a_ctrl_c_handled_inside_exec_code_exits_130_under_python_m_once_marked_handled(tmp_path):
    """A `python -m` command whose Ctrl-C lands in code run by `exec` and is handled outside it, marked handled
    (`interrupt_handled`), exits with the 130 it returns. Oracle: the exit status the OS reports for a real SIGINT.
    Without the mark, CPython 3.11 reports death by SIGINT (-2) for the same run (checked by hand: 3 of 3); that
    control is not asserted here, since it is the interpreter's behaviour, not ours."""
    (tmp_path / "exec_interrupted.py").write_text(_EXEC_INTERRUPTED, encoding="utf-8")
    proc = subprocess.Popen([sys.executable, "-m", "exec_interrupted", "handled"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"  # inside the exec'd loop
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert "interrupted" in err
    assert proc.returncode == 130, err


_NATIVE_INIT = '''
import sys
print("ready", flush=True)
try:  # as a pybind11 extension's initialisation does with an exception it meets
    sys.stdin.readline()  # the test sends SIGINT, then this line
except KeyboardInterrupt as e:
    raise ImportError("initialization failed") from e
loaded = True
'''

_IMPORTS_NATIVE = '''
import sys
def main():
    from prsm_ros.interrupts import import_native, interrupt_handled
    try:
        import_native("native_init")
        print("not interrupted", file=sys.stderr)
        return 0
    except KeyboardInterrupt:
        interrupt_handled()
        print("interrupted; module loaded:", sys.modules["native_init"].loaded, file=sys.stderr)
        return 130
if __name__ == "__main__":
    sys.exit(main())
'''


def test_a_ctrl_c_during_a_native_modules_import_reaches_the_commands_handler_once_the_module_is_loaded(tmp_path):
    """`import_native` holds a SIGINT that lands in a module's initialisation and delivers it afterwards: the
    module loads whole and the command's own Ctrl-C handler runs (exit 130), where the module, converting the
    interrupt as a pybind11 extension does (scipy's `_highspy`), would otherwise end the command in an
    ImportError. Oracle: the real signal's order against the module's own progress, and the exit status."""
    (tmp_path / "native_init.py").write_text(_NATIVE_INIT, encoding="utf-8")
    (tmp_path / "imports_native.py").write_text(_IMPORTS_NATIVE, encoding="utf-8")
    proc = subprocess.Popen([sys.executable, "-m", "imports_native"], cwd=tmp_path, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])})
    try:
        assert proc.stdout.readline().strip() == "ready"  # inside the module's initialisation
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate("go\n", timeout=60)
    finally:
        proc.kill()
    assert "interrupted; module loaded: True" in err, err
    assert proc.returncode == 130, err
