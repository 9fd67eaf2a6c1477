"""Build the documentation site — the README, every docs/ page and the API reference — with pdoc.

    python -m prsm_ros.cli.docs -o site        # then open site/index.html

pdoc because the code's numpy-style docstrings are the reference already: it renders them with
no configuration to keep in step with the code, and links every backticked name it knows. The
prose pages go in as the docstrings of a generated package, `manual` (one module per page:
`manual` is the README, `manual.node` docs/node.md, ...), so prose and API are one site with one
search. The API covers the library, `prsm_sim` (its package page is the user guide and
`prsm_sim.models` carries the model reference), and the ROS side, `prsm_ros`. The landing page
(`index.html`) says what prsm is, repeats the README's quick start and lists the pages and the
API, all taken from the README and the pages' titles when the site is built, so it cannot drift
from them. Errors print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from pathlib import Path

PACKAGES = ("prsm_sim", "prsm_ros")
NOTEBOOK = "examples/getting_started.ipynb"


def modules() -> list[str]:
    """`prsm_sim` with its direct submodules, and `prsm_ros` (pdoc walks each subpackage itself).

    `prsm_sim`'s are named one by one because pdoc only walks into submodules a package lists in
    `__all__`, and `prsm_sim.__all__` lists the API's names, not its modules; `prsm_ros` has no
    `__all__`, so pdoc walks all of it.
    """
    import pkgutil

    import prsm_sim

    return (["prsm_sim"] + [m.name for m in pkgutil.iter_modules(prsm_sim.__path__, "prsm_sim.")]
            + ["prsm_ros"])


ROOT = Path(__file__).resolve().parents[2]
MANUAL = "manual"


def manual_package(folder: Path) -> Path:
    """Write the `manual` package into `folder`: the README as its docstring, one module per docs/ page."""
    pkg = folder / MANUAL
    pkg.mkdir(parents=True, exist_ok=True)

    def module(path: Path, source: Path) -> None:
        path.write_text(f'"""\n.. include:: {source.as_posix()}\n"""\n', encoding="utf-8")

    module(pkg / "__init__.py", ROOT / "README.md")
    for page in sorted((ROOT / "docs").glob("*.md")):
        module(pkg / f"{page.stem.replace('-', '_')}.py", page)
    return pkg


def _section(markdown: str, title: str) -> str:
    """The body of the `## title` section of `markdown` (up to the next `## `)."""
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", markdown, flags=re.S | re.M)
    return m.group(1).strip() if m else ""


def _site_links(markdown: str) -> str:
    """Links to docs/X.md as the site's manual/X.html; lines only the docs test reads are dropped."""
    markdown = re.sub(r"\]\(docs/([\w-]+)\.md(#[^)]*)?\)",
                      lambda m: f"](manual/{m.group(1).replace('-', '_')}.html{m.group(2) or ''})", markdown)
    markdown = re.sub(r"^```(\w+)[^\n]*$", r"```\1", markdown, flags=re.M)  # the docs test's info strings
    return "\n".join(line for line in markdown.splitlines() if not line.startswith("# the docs test runs:"))


def landing_markdown() -> str:
    """The landing page: the README's introduction and quick start, the pages by title, the API."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    title, _, rest = readme.partition("\n")
    intro = rest[:rest.index("\n## ")].strip() if "\n## " in rest else rest.strip()
    pages = []
    for page in sorted((ROOT / "docs").glob("*.md")):
        first = page.read_text(encoding="utf-8").split("\n", 1)[0].lstrip("# ").strip()
        pages.append(f"- [{first}](manual/{page.stem.replace('-', '_')}.html)")
    api = []
    for name in PACKAGES:
        first = importlib.import_module(name).__doc__.strip().splitlines()[0]
        api.append(f"- [`{name}`]({name}.html): {first.removeprefix(name + ':').strip()}")
    return "\n\n".join([
        title, _site_links(intro),
        "## Quick start", _site_links(_section(readme, "Quick start")),
        f"A notebook to start from: `{NOTEBOOK}` in the repository (a plant from a preset and from a "
        "datasheet, a closed loop, internal loads, a saved state, a bag).",
        "## The pages", "- [The README](manual.html): the whole introduction, commands and where to read more\n"
        + "\n".join(pages),
        "## The API", "\n".join(api)])


# The landing page: pdoc's frame and module list, the landing text as its content.
INDEX_TEMPLATE = """{% extends "frame.html.jinja2" %}
{% block title %}prsm{% endblock %}
{% block nav %}
    <h2>Modules</h2>
    <ul>
        {% for submodule in all_modules if "._" not in submodule and not submodule.startswith("_") %}
            <li><a href="{{ submodule.replace(".","/") }}.html">{{ submodule }}</a></li>
        {% endfor %}
    </ul>
{% endblock %}
{% block content %}
    <main class="pdoc"><section class="module-info">{{ prsm_landing | safe }}</section></main>
    {% if search %}{% include "search.html.jinja2" %}{% endif %}
{% endblock %}
"""


def build(output_dir: Path) -> list[Path]:
    """Render the site into `output_dir` (created if missing); returns the HTML files written."""
    import tempfile

    import pdoc
    import pdoc.render
    import pdoc.render_helpers

    import prsm_sim

    output_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="prsm_docs_") as tmp:
        templates = Path(tmp) / "templates"
        templates.mkdir()
        (templates / "index.html.jinja2").write_text(INDEX_TEMPLATE, encoding="utf-8")
        pdoc.render.configure(docformat="numpy", show_source=True, search=True,
                              footer_text=f"prsm {prsm_sim.__version__}", template_directory=templates)
        pdoc.render.env.globals["prsm_landing"] = pdoc.render_helpers.to_html(landing_markdown())
        manual_package(Path(tmp))
        sys.path.insert(0, tmp)
        try:
            pdoc.pdoc(MANUAL, *modules(), output_directory=output_dir)
        finally:
            sys.path.remove(tmp)
            for name in [m for m in sys.modules if m == MANUAL or m.startswith(MANUAL + ".")]:
                del sys.modules[name]
    return sorted(output_dir.rglob("*.html"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m prsm_ros.cli.docs", description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output-dir", type=Path, default=Path("site"),
                    help="directory for the HTML (default: ./site)")
    args = ap.parse_args(argv)
    try:
        import pdoc  # noqa: F401
    except ImportError:
        print("docs: pdoc is not installed; pip install -e '.[docs]'", file=sys.stderr)
        return 2
    if args.output_dir.exists() and not args.output_dir.is_dir():
        print(f"docs: --output-dir = {str(args.output_dir)!r}: exists and is not a directory", file=sys.stderr)
        return 2
    files = build(args.output_dir)
    print(f"{len(files)} pages in {args.output_dir}/ (open {args.output_dir / 'index.html'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
