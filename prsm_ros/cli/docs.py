"""Build the documentation site — the README, every docs/ page and the API reference — with pdoc.

    python -m prsm_ros.cli.docs -o site        # then open site/index.html

pdoc because the code's numpy-style docstrings are the reference already: it renders them with
no configuration to keep in step with the code, and links every backticked name it knows. The
prose pages go in as the docstrings of a generated package, `manual` (one module per page:
`manual` is the README, `manual.node` docs/node.md, ...), so prose and API are one site with one
search. The API covers the library, `prsm_sim`; its package page is the user guide and
`prsm_sim.models` carries the model reference. Errors print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

PACKAGE = "prsm_sim"


def modules() -> list[str]:
    """The package and its direct submodules (pdoc walks each subpackage itself).

    Named one by one because pdoc only walks into submodules a package lists in `__all__`,
    and `prsm_sim.__all__` lists the API's names, not its modules.
    """
    import pkgutil

    import prsm_sim

    return [PACKAGE] + [m.name for m in pkgutil.iter_modules(prsm_sim.__path__, f"{PACKAGE}.")]


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


def build(output_dir: Path) -> list[Path]:
    """Render the site into `output_dir` (created if missing); returns the HTML files written."""
    import tempfile

    import pdoc
    import pdoc.render

    import prsm_sim

    pdoc.render.configure(docformat="numpy", show_source=True, search=True,
                          footer_text=f"prsm {prsm_sim.__version__}")
    output_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="prsm_docs_") as tmp:
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
