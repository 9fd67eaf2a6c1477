"""The documentation builds, its example code runs, and every citation of the model reference resolves.

- the user guide's Python blocks are executed in order, as a notebook would run them;
- the one docs command (`python -m prsm_ros.cli.docs`) builds the API reference and the guide
  into a temporary directory, and the pages hold what they should;
- every `docs/model.md §n` cited in code and docs names a section that exists, and nothing in
  the repository points at a physics reference outside it.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
GUIDE = ROOT / "docs" / "guide.md"
MODEL = ROOT / "docs" / "model.md"


def python_blocks(markdown: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", markdown, flags=re.S | re.M)


def test_guide_examples_run(monkeypatch, capsys):
    pytest.importorskip("pandas")
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")  # no display; a notebook shows the figure itself
    blocks = python_blocks(GUIDE.read_text(encoding="utf-8"))
    assert len(blocks) >= 6
    # the notebook promise: the first block starts the five-line run from the package's names
    assert "from prsm_sim import Simulator, preset" in blocks[0]
    namespace: dict = {"__name__": "guide"}
    for k, code in enumerate(blocks):
        exec(compile(code, f"{GUIDE.name}[block {k}]", "exec"), namespace)
    printed = capsys.readouterr().out
    # the first block's claim: Jones 2016 eq. 42's ratio, 2.669
    assert "ω_S/ω_C = 2.669" in printed
    # the error section printed the two refusals, one line each
    assert "run() takes a 1-D array with one torque per step" in printed
    assert "geometry.n_rollers = 2" in printed
    import matplotlib.pyplot as plt

    plt.close("all")


def test_docs_command_builds_reference_and_guide(tmp_path, capsys):
    pytest.importorskip("pdoc")
    from prsm_ros.cli import docs

    out = tmp_path / "site"
    assert docs.main(["-o", str(out)]) == 0
    assert "pages in" in capsys.readouterr().out
    assert (out / "index.html").is_file()
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


def test_readme_python_example_runs():
    pytest.importorskip("pandas")
    blocks = python_blocks((ROOT / "README.md").read_text(encoding="utf-8").replace("\n  ", "\n"))
    assert blocks and "from prsm_sim import Simulator, preset" in blocks[0]
    namespace: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)
    assert len(namespace["traj"]) == 1000
