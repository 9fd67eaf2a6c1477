"""The documentation builds, every block in it runs as written, and every citation of the model reference resolves.

- every shell and Python block of README.md and docs/*.md runs, page by page, in a fresh folder,
  and what a page shows a command printing is what it prints (conventions below);
- the README stays a user's document (length, no issue numbers or dated figures, every command listed);
- the one docs command (`python -m prsm_ros.cli.docs`) builds the API reference and the guide
  into a temporary directory, and the pages hold what they should;
- every `docs/model.md §n` cited in code and docs names a section that exists, and nothing in
  the repository points at a physics reference outside it.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
GUIDE = ROOT / "docs" / "guide.md"
MODEL = ROOT / "docs" / "model.md"


def python_blocks(markdown: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", markdown, flags=re.S | re.M)


# ---- every block of README and docs/*.md, run as written --------------------------------------
#
# A page's blocks run in order in one fresh temporary folder: shell blocks (bash, sh) with bash,
# the commands of this tree first on PATH; Python blocks exec'd in one namespace per page, as a
# notebook runs them. Conventions a reader sees on the page:
# - a block whose first line is `# not run by the docs test: REASON` is not run (the reason says why);
# - `# the docs test runs: COMMAND` runs COMMAND instead of the block (the quick start: its install
#   is the test environment's own);
# - a data block (yaml, json, xml, text) whose first line is `# file: NAME` is written to NAME first;
# - a ```text block right after a run block is the output it prints: each of its lines must appear
#   in that output, in order (`…` stands for anything); numbers must be equal, or within the
#   tolerance its info string states (```text tolerance=50%, for realtime runs, said beside it).
# Background processes a shell block starts (`prsm-node … &`) are stopped when the page ends.

PAGES = sorted([ROOT / "README.md", *ROOT.glob("docs/*.md")], key=lambda p: (p.name != "README.md", p.name))
# The library's pages run in the README's test command (about half a minute); the pages that start
# nodes, demos, Ray or benchmarks run in the slow tier `.ci/run` runs after it (several minutes).
FAST_PAGES = {"guide.md"}  # the rest run in the slow tier
SHELLS = ("bash", "sh", "shell")
DATA = ("yaml", "yml", "json", "xml", "text", "toml")
SKIP_MARK = "# not run by the docs test:"
INSTEAD_MARK = "# the docs test runs:"
FILE_MARK = "# file:"
BLOCK_TIMEOUT_S = 600


def fenced_blocks(markdown: str) -> list[tuple[str, str, int]]:
    """(info string, body, line number) of every fenced block, in page order."""
    out = []
    for m in re.finditer(r"^```([^\n`]*)\n(.*?)^```[ \t]*$", markdown, flags=re.S | re.M):
        out.append((m.group(1).strip(), m.group(2), markdown.count("\n", 0, m.start()) + 1))
    return out


def page_steps(markdown: str) -> list[dict]:
    """The page's blocks as steps: kind (shell, python, file, skip), body, expected output (or None)."""
    blocks = fenced_blocks(markdown)
    steps: list[dict] = []
    for info, body, line in blocks:
        lang = info.split()[0] if info else ""
        first = body.split("\n", 1)[0].strip()
        if lang == "text" and steps and steps[-1].get("expects") is None and steps[-1]["kind"] in ("shell", "python") \
                and steps[-1]["end"] == _previous_end(markdown, line):
            steps[-1]["expects"] = (body, _tolerance(info))
            continue
        step = {"line": line, "body": body, "expects": None, "end": _block_end(markdown, line)}
        if first.startswith(SKIP_MARK):
            step["kind"] = "skip"
            assert first[len(SKIP_MARK):].strip(), f"line {line}: a skipped block must say why"
        elif first.startswith(INSTEAD_MARK):
            step.update(kind="shell", body=first[len(INSTEAD_MARK):].strip().strip("`"))
        elif lang in SHELLS:
            step["kind"] = "shell"
        elif lang == "python":
            step["kind"] = "python"
        elif lang in DATA and first.startswith(FILE_MARK):
            step.update(kind="file", name=first[len(FILE_MARK):].strip())
        else:
            step["kind"] = "data"
        steps.append(step)
    return steps


def _block_end(markdown: str, line: int) -> int:
    """The line of a block's closing fence."""
    lines = markdown.split("\n")
    k = line
    while not lines[k].startswith("```"):
        k += 1
    return k + 1


def _previous_end(markdown: str, line: int) -> int:
    """The closing-fence line of the block before the one opening at `line`, if only blank lines lie between."""
    lines = markdown.split("\n")
    k = line - 2
    while k >= 0 and not lines[k].strip():
        k -= 1
    return k + 1 if k >= 0 and lines[k].startswith("```") else -1


def _tolerance(info: str) -> float | None:
    m = re.search(r"tolerance=(\d+(?:\.\d+)?)%", info)
    return float(m.group(1)) / 100 if m else None


NUMBER = r"[-+]?(?:\d[\d,]*\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def _line_pattern(expected: str, tolerant: bool) -> tuple[re.Pattern, list[float]]:
    """A regex for one expected line ("…" = anything, runs of spaces = any spaces) and its numbers."""
    parts, numbers = [], []
    for piece in re.split(r"(…|\s+|" + NUMBER + ")", expected.strip()):
        if not piece:
            continue
        if piece == "…":
            parts.append(".*?")
        elif piece.isspace():
            parts.append(r"\s+")
        elif tolerant and re.fullmatch(NUMBER, piece) and re.search(r"\d", piece):
            parts.append("(" + NUMBER + ")")
            numbers.append(float(piece.replace(",", "")))
        else:
            parts.append(re.escape(piece))
    return re.compile("".join(parts)), numbers


def check_output(actual: str, expected: str, tolerance: float | None, where: str) -> None:
    """Each expected line in order in `actual`; numbers equal, or within `tolerance` (relative)."""
    lines = actual.splitlines()
    at = 0
    for want in (w for w in expected.splitlines() if w.strip()):
        pattern, numbers = _line_pattern(want, tolerance is not None)
        for k in range(at, len(lines)):
            m = pattern.search(lines[k])
            if m and all(abs(float(g.replace(",", "")) - n) <= tolerance * max(abs(n), 1e-300)
                         for g, n in zip(m.groups(), numbers)):
                at = k + 1
                break
        else:
            raise AssertionError(f"{where}: expected output line not found (in order"
                                 f"{', within ' + format(tolerance, '.0%') if tolerance is not None else ''}):\n"
                                 f"  {want.strip()}\nactual output:\n{actual[-4000:]}")


def console_scripts() -> dict[str, str]:
    """name → "module:function" of pyproject's [project.scripts] (read without tomllib: Python 3.10 has none)."""
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    section = text.split("[project.scripts]", 1)[1].split("\n[", 1)[0]
    return dict(re.findall(r'^([\w-]+)\s*=\s*"([\w.]+:\w+)"', section, flags=re.M))


def command_shims(folder: Path) -> Path:
    """A bin folder with this tree's console scripts and `python`, so blocks run the code under test."""
    scripts = console_scripts()
    bin_dir = folder / "bin"
    bin_dir.mkdir(exist_ok=True)
    for name, target in scripts.items():
        module, func = target.split(":")
        path = bin_dir / name
        path.write_text(f"#!{sys.executable}\nimport sys\nfrom {module} import {func}\nsys.exit({func}())\n")
        path.chmod(0o755)
    for name in ("python", "python3"):  # a script, not a link: a linked venv python would not find its venv
        (bin_dir / name).write_text(f'#!/bin/sh\nexec "{sys.executable}" "$@"\n')
        (bin_dir / name).chmod(0o755)
    return bin_dir


def _page_id(p: Path) -> str:
    return p.relative_to(ROOT).as_posix()


def _runnable(page: Path) -> bool:
    return any(s["kind"] in ("shell", "python") for s in page_steps(page.read_text(encoding="utf-8")))


# pages of prose only (no fenced block to run: the model reference, the architecture, the threat model)
# are not collected
@pytest.mark.parametrize("page", [pytest.param(p, id=_page_id(p), marks=[] if p.name in FAST_PAGES else [pytest.mark.slow])
                                  for p in PAGES if _runnable(p)])
def test_every_block_of_the_page_runs_as_written(page, tmp_path, monkeypatch, capsys):
    import contextlib
    import io
    import os
    import signal
    import subprocess

    steps = page_steps(page.read_text(encoding="utf-8"))
    work = tmp_path / "work"
    work.mkdir()
    bin_dir = command_shims(tmp_path)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
           "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}", "PYTHONUNBUFFERED": "1",
           "MPLBACKEND": "Agg"}
    monkeypatch.chdir(work)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace: dict = {"__name__": page.stem}
    groups: list[int] = []
    try:
        for step in steps:
            where = f"{_page_id(page)}:{step['line']}"
            if step["kind"] == "file":
                (work / step["name"]).write_text(step["body"].split("\n", 1)[1], encoding="utf-8")
                continue
            if step["kind"] == "shell":
                proc = subprocess.Popen(["bash", "-euo", "pipefail", "-c", step["body"]], cwd=work, env=env,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                        start_new_session=True)
                groups.append(proc.pid)
                try:
                    out, err = proc.communicate(timeout=BLOCK_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    out, err = proc.communicate()
                    raise AssertionError(f"{where}: still running after {BLOCK_TIMEOUT_S} s\n{err[-3000:]}") from None
                assert proc.returncode == 0, f"{where}: exit status {proc.returncode}\n{out[-2000:]}\n{err[-4000:]}"
            elif step["kind"] == "python":
                buf = io.StringIO()
                with contextlib.redirect_stdout(buf):
                    exec(compile(step["body"], where, "exec"), namespace)
                out = buf.getvalue()
            else:
                continue
            if step["expects"] is not None:
                check_output(out, *step["expects"], where)
    finally:
        for pgid in groups:  # what a block left running in the background
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(pgid, signal.SIGTERM)  # background jobs of a script ignore SIGINT
        for pgid in groups:
            for _ in range(100):
                try:
                    os.killpg(pgid, 0)
                except (ProcessLookupError, PermissionError):
                    break
                import time
                time.sleep(0.1)
            else:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(pgid, signal.SIGKILL)
        import matplotlib.pyplot as plt
        plt.close("all")


def test_readme_test_command_is_the_one_ci_runs():
    """The quick start's second command is, verbatim, what `.ci/run` runs: its install line, the
    quality gate (ruff, mypy on the core), then `python -m pytest`."""
    lines = [ln for ln in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
             if ln.strip() and not ln.startswith("#")]
    install = next(i for i, ln in enumerate(lines) if ln.startswith("python3 -m venv"))
    assert lines[install + 1:install + 4] == ["ruff check .", "python -m mypy prsm_sim", "python -m pytest"]
    ci = [lines[install] + " && python -m pytest"]
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    start = readme.index("## Quick start")
    quick = fenced_blocks(readme[start:])[0][1]
    commands = [ln for ln in quick.splitlines() if ln.strip() and not ln.startswith("#")]
    assert len(commands) == 2, commands
    assert commands[1] == ci[0]
    assert "pip install -e '.[all]'" in commands[0] and commands[0].endswith("prsm-demo")


def test_readme_is_for_users():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    user_docs = [ROOT / "README.md", *ROOT.glob("docs/*.md")]
    for path in user_docs:
        t = path.read_text(encoding="utf-8")
        assert not re.search(r"\(issues? \d+|issue \d+\)|issues? \d+[,;]", t), f"{path.name}: an issue number"
        assert not re.search(r"\b20\d\d-\d\d-\d\d\b", t), f"{path.name}: a dated figure"
        assert "Firecracker" not in t and "helpers running" not in t, f"{path.name}: a machine anecdote"
    # every command of the package is in the README's table
    scripts = console_scripts()
    table = text[text.index("## Commands"):]
    for name in scripts:
        assert f"`{name}" in table, f"{name} missing from the README's command table"


@pytest.mark.slow
def test_docs_command_builds_reference_and_guide(tmp_path, capsys):
    pytest.importorskip("pdoc")
    from prsm_ros.cli import docs

    out = tmp_path / "site"
    assert docs.main(["-o", str(out)]) == 0
    assert "pages in" in capsys.readouterr().out
    # the landing page: what prsm is, the quick start, every page by its title, both APIs
    index = (out / "index.html").read_text(encoding="utf-8")
    assert "planetary roller screw" in index and 'id="quick-start"' in index and "prsm-demo" in index
    for page in ROOT.glob("docs/*.md"):
        title = page.read_text(encoding="utf-8").split("\n", 1)[0].lstrip("# ").split("`")[0].strip()
        assert f'href="manual/{page.stem.replace("-", "_")}.html"' in index and title in index, page.name
    assert 'href="prsm_sim.html"' in index and 'href="prsm_ros.html"' in index
    assert "tolerance=" not in index and "the docs test runs" not in index
    live = (out / "prsm_ros" / "live" / "foxglove_server.html").read_text(encoding="utf-8")
    assert 'id="FoxgloveLive"' in live  # the prsm_ros API, walked by pdoc
    # the prose pages are in the site: the README as the manual's front page, one page per docs/ file
    manual = (out / "manual.html").read_text(encoding="utf-8")
    assert 'id="quick-start"' in manual
    for page in ROOT.glob("docs/*.md"):
        assert (out / "manual" / f"{page.stem.replace('-', '_')}.html").is_file(), page.name
    package = (out / "prsm_sim.html").read_text(encoding="utf-8")
    # the guide is the package's front page; the API documents Simulator with its docstring
    assert 'id="a-run-in-five-lines"' in package
    assert 'id="Simulator"' in package and "A model with its current state and step counter" in package
    simulator = (out / "prsm_sim" / "simulator.html").read_text(encoding="utf-8")
    assert '<h6 id="parameters">Parameters</h6>' in simulator  # numpy sections rendered, not raw
    models = (out / "prsm_sim" / "models.html").read_text(encoding="utf-8")
    assert "Where the threads really touch: the tangency solver" in models
    assert "include::" not in re.sub(r"<pre>.*?</pre>", "", package + models, flags=re.S)


def test_docs_command_refuses_a_file_as_output(tmp_path, capsys):
    pytest.importorskip("pdoc")
    from prsm_ros.cli import docs

    f = tmp_path / "file"
    f.write_text("x")
    assert docs.main(["-o", str(f)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists and is not a directory" in err


def model_sections() -> set[str]:
    heads = re.findall(r"^#{2,3} (\d+(?:\.\d+)?)\.? ", MODEL.read_text(encoding="utf-8"), flags=re.M)
    return set(heads)


def test_model_reference_keeps_its_section_numbers():
    assert {"1", "2", "3", "4", "4.1", "4.2", "4.3", "5", "6"} <= model_sections()


def test_every_model_citation_resolves():
    sections = model_sections()
    cited = {}
    files = [*ROOT.glob("prsm_sim/**/*.py"), *ROOT.glob("prsm_ros/**/*.py"), *ROOT.glob("tests/*.py"),
             ROOT / "README.md", *ROOT.glob("docs/*.md")]
    for path in files:
        for m in re.finditer(r"docs/model\.md §(\d+(?:\.\d+)?)(?:[–-](\d+(?:\.\d+)?))?", path.read_text(encoding="utf-8")):
            for sec in filter(None, m.groups()):
                cited.setdefault(sec, []).append(path.relative_to(ROOT).as_posix())
    assert cited, "no citations found: the pattern is wrong"
    missing = {s: where for s, where in cited.items() if s not in sections}
    assert not missing, f"citations of sections docs/model.md does not have: {missing}"


def test_no_reference_outside_the_repository():
    pattern = re.compile(r"MODEL\.md|\.\./shared|/work/shared")
    files = [*ROOT.glob("prsm_sim/**/*.py"), *ROOT.glob("prsm_ros/**/*.py"), ROOT / "README.md",
             *ROOT.glob("docs/*.md"), ROOT / "pyproject.toml"]
    hits = [f"{p.relative_to(ROOT)}:{n}" for p in files
            for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if pattern.search(line)]
    assert not hits, f"point at docs/ instead: {hits}"


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_links_into_the_model_reference_resolve():
    anchors = {github_slug(h) for h in re.findall(r"^#+ (.+)$", MODEL.read_text(encoding="utf-8"), flags=re.M)}
    links = []
    for path in (ROOT / "README.md", *ROOT.glob("docs/*.md")):
        text = path.read_text(encoding="utf-8")
        links += [(path.name, a) for a in re.findall(r"\]\((?:docs/)?model\.md#([^)]+)\)", text)]
        if path == MODEL:
            links += [(path.name, a) for a in re.findall(r"\]\(#([^)]+)\)", text)]
    assert links, "no links found: the pattern is wrong"
    broken = [(name, a) for name, a in links if a not in anchors]
    assert not broken, f"links to headings docs/model.md does not have: {broken}"
