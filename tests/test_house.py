"""The house limits, checked on the source of `prsm_sim` and `prsm_ros`:

- no function (a method or a nested function too) over 80 lines, from its `def` to its last line,
  docstring included;
- no function above cyclomatic complexity 25, as radon counts it (`radon cc`, its Python API here);
- no class over 450 lines;
- no comparison of a model's name to a string (`model == "elastic"`, `name in ("fu2018", ...)`)
  outside the registry (`prsm_sim/models/registry.py`): callers ask a model what it can do.

`ALLOWED` lists what exceeds a limit today, by file and qualified name, so that any new finding
fails; an entry that no longer exceeds its limit fails too, so the list only shrinks.
Oracle: Python's `ast` for lines and comparisons, radon for complexity; nothing is imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

radon_complexity = pytest.importorskip("radon.complexity")
radon_visitors = pytest.importorskip("radon.visitors")

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("prsm_sim", "prsm_ros")
MAX_FUNCTION_LINES = 80
MAX_COMPLEXITY = 25
MAX_CLASS_LINES = 450
REGISTRY = "prsm_sim/models/registry.py"
MODEL_NAMES = ("ideal", "jones2016", "fu2018", "elastic")  # the registry's keys (prsm_sim.models.registry.MODELS)

# (kind, file, qualified name) of each finding the work under way removes; empty it as that work lands.
ALLOWED: set[tuple[str, str, str]] = set()


def _sources() -> dict[str, str]:
    return {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8")
            for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))}


SOURCES = _sources()


def _defs(tree: ast.AST, prefix: str = ""):
    """(qualified name, node) of every function and class, nested ones included."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            name = f"{prefix}{node.name}"
            yield name, node
            yield from _defs(node, name + ".")
        else:
            yield from _defs(node, prefix)


def _blocks(blocks, prefix: str = ""):
    """(qualified name, complexity) of every function radon scores, methods and closures included."""
    for b in blocks:
        if getattr(b, "is_method", False) and not prefix:
            continue  # cc_visit lists each method also beside its class
        if isinstance(b, radon_visitors.Class):
            yield from _blocks(b.methods, f"{prefix}{b.name}.")
            yield from _blocks(b.inner_classes, f"{prefix}{b.name}.")
        else:
            yield f"{prefix}{b.name}", b.complexity
            yield from _blocks(b.closures, f"{prefix}{b.name}.")


def _is_model_name(node: ast.AST) -> bool:
    if isinstance(node, ast.Constant):
        return node.value in MODEL_NAMES
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return any(_is_model_name(e) for e in node.elts)
    return False


def _model_name_comparisons(tree: ast.AST) -> list[int]:
    """Lines where a value is compared to a model's name (==, !=, in, not in a collection)."""
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Compare):
            continue
        for op, left, right in zip(node.ops, [node.left, *node.comparators], node.comparators):
            if isinstance(op, (ast.Eq, ast.NotEq)) and (_is_model_name(left) or _is_model_name(right)):
                lines.append(node.lineno)
            elif isinstance(op, (ast.In, ast.NotIn)) and _is_model_name(right) and not isinstance(right, ast.Constant):
                lines.append(node.lineno)
    return sorted(set(lines))


def findings() -> dict[tuple[str, str, str], str]:
    """Every finding as (kind, file, name) → what it measures."""
    out: dict[tuple[str, str, str], str] = {}
    for path, text in SOURCES.items():
        tree = ast.parse(text)
        defs = list(_defs(tree))
        for name, node in defs:
            n = node.end_lineno - node.lineno + 1
            if isinstance(node, ast.ClassDef):
                if n > MAX_CLASS_LINES:
                    out[("class-lines", path, name)] = f"{n} lines (limit {MAX_CLASS_LINES})"
            elif n > MAX_FUNCTION_LINES:
                out[("function-lines", path, name)] = f"{n} lines (limit {MAX_FUNCTION_LINES})"
        for name, cc in _blocks(radon_complexity.cc_visit(text)):
            if cc > MAX_COMPLEXITY:
                out[("complexity", path, name)] = f"complexity {cc} (limit {MAX_COMPLEXITY})"
        if path != REGISTRY:
            spans = [(node.lineno, node.end_lineno, name) for name, node in defs]
            for line in _model_name_comparisons(tree):
                # keyed by the innermost enclosing definition, so that edits elsewhere in the file keep the key
                inside = [(a, name) for a, b, name in spans if a <= line <= b]
                where = max(inside)[1] if inside else "<module>"
                key = ("model-name", path, where)
                out[key] = out.get(key, "compares a model's name at line") + f" {line}"
    return out


FINDINGS = findings()


def _rows(keys) -> str:
    return "\n  ".join(f"{f}: {name}: {kind} {FINDINGS.get((kind, f, name), '')}" for kind, f, name in sorted(keys))


@pytest.mark.parametrize("kind", ["function-lines", "complexity", "class-lines", "model-name"])
def test_no_new_finding(kind):
    new = {k for k in FINDINGS if k[0] == kind} - ALLOWED
    assert not new, f"over the house limit ({kind}); split the code or ask the model:\n  {_rows(new)}"


def test_the_allow_list_holds_only_present_findings():
    gone = ALLOWED - set(FINDINGS)
    assert not gone, f"no longer found; remove from ALLOWED in tests/test_house.py:\n  {_rows(gone)}"


def test_the_checks_find_what_they_look_for():
    """A long function, a complex one and a model-name comparison are found; clean code is not."""
    long_fn = "def f():\n" + "    x = 1\n" * 80
    tree = ast.parse(long_fn)
    (name, node), = _defs(tree)
    assert (name, node.end_lineno - node.lineno + 1) == ("f", 81)
    branchy = "class A:\n    def g(self, x):\n" + "".join(f"        if x == {i}:\n            return {i}\n"
                                                         for i in range(25))
    assert dict(_blocks(radon_complexity.cc_visit(branchy))) == {"A.g": 26}
    assert [k for k, _ in _blocks(radon_complexity.cc_visit("def f():\n    def g():\n        pass\n"))] == ["f", "f.g"]
    names = "if model == 'elastic': pass\nif m.name in ('fu2018', 'ideal'): pass\nif s in 'elastic': pass\n" \
            "if kind == 'coulomb': pass\n"
    assert _model_name_comparisons(ast.parse(names)) == [1, 2]


def test_pytestmark_sits_above_the_tests():
    """A module's `pytestmark` (its tier, its fixtures) is read where the module starts, before any test."""
    late = []
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        body = ast.parse(path.read_text(encoding="utf-8")).body
        first_def = next((n.lineno for n in body if isinstance(n, (ast.FunctionDef, ast.ClassDef))), None)
        for n in body:
            if (isinstance(n, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "pytestmark" for t in n.targets)
                    and first_def is not None and n.lineno > first_def):
                late.append(f"{path.relative_to(ROOT)}:{n.lineno}")
    assert not late, "pytestmark below the first test; move it to the top:\n  " + "\n  ".join(late)
