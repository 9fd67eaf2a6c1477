"""Build the API reference and the user guide from the docstrings, with pdoc (the `docs` extra).

    python -m prsm_ros.cli.docs -o site        # then open site/index.html

The reference covers the library, `prsm_sim`. Its package page is the user guide
(docs/guide.md, included by `prsm_sim`'s docstring) and `prsm_sim.models` carries the model
reference (docs/model.md); pdoc renders the numpy-style docstrings and links every
backticked name it knows. Errors print one line and exit with status 2.
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


def build(output_dir: Path) -> list[Path]:
    """Render the reference into `output_dir` (created if missing); returns the HTML files written."""
    import pdoc
    import pdoc.render

    import prsm_sim

    pdoc.render.configure(docformat="numpy", show_source=True, search=True,
                          footer_text=f"prsm {prsm_sim.__version__}")
    output_dir.mkdir(parents=True, exist_ok=True)
    pdoc.pdoc(*modules(), output_directory=output_dir)
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
