"""The layering rule, checked by walking every module's imports (README: "Layout").

Data flows one way. A package may import only packages of its own rank or lower, and never
another package's private (``_``-prefixed) modules: what a package offers is what its
``__init__`` re-exports.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "vdsbi"

#: Rank of each package: a package may import packages of equal or lower rank only.
LAYERS: dict[str, int] = {
    "runtime": 0,
    "simulator": 0,
    "io": 1,
    "problem": 2,
    "estimation": 3,
    "inference": 4,
    "diagnostics": 5,
    "discovery": 6,
    "api": 7,
    "fleet": 8,
    "cli": 9,
}


def _modules():
    for path in sorted(ROOT.rglob("*.py")):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield path, parts


def _imports(path: Path, parts: tuple[str, ...]):
    """Absolute dotted names of every `vdsbi` module or name this file imports (any depth)."""
    is_pkg = path.name == "__init__.py"
    package = parts if is_pkg else parts[:-1]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "vdsbi":
                    yield node.lineno, tuple(alias.name.split("."))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                mod = base + tuple(node.module.split(".")) if node.module else base
            else:
                mod = tuple((node.module or "").split("."))
            if mod[0] != "vdsbi":
                continue
            if node.module is None:  # `from .. import api`: the names are modules
                for alias in node.names:
                    yield node.lineno, mod + (alias.name,)
            else:
                yield node.lineno, mod


def _package(dotted: tuple[str, ...]) -> str | None:
    return dotted[1] if len(dotted) > 1 and dotted[1] in LAYERS else None


def test_every_package_has_a_layer():
    found = {p.name for p in ROOT.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    found |= {p.stem for p in ROOT.glob("*.py") if p.stem != "__init__"}
    assert found <= set(LAYERS), f"packages without a layer: {sorted(found - set(LAYERS))}"


def _violations():
    lower, private = [], []
    for path, parts in _modules():
        src = _package(parts)
        if src is None:  # vdsbi/__init__.py
            continue
        for line, target in _imports(path, parts):
            dst = _package(target)
            if dst is None or dst == src:
                continue
            where = f"{path.relative_to(ROOT.parent)}:{line} imports {'.'.join(target)}"
            if LAYERS[dst] > LAYERS[src]:
                lower.append(where)
            if len(target) > 2 and target[2].startswith("_"):
                private.append(where)
    return lower, private


def test_lower_layers_never_import_higher_ones():
    lower, _ = _violations()
    assert not lower, "a lower layer imports a higher one:\n" + "\n".join(lower)


def test_no_package_imports_another_packages_private_modules():
    _, private = _violations()
    assert not private, "imports of another package's private module:\n" + "\n".join(private)


@pytest.mark.parametrize("source, expect", [("from ..discovery import x", True), ("from . import y", False)])
def test_the_walker_sees_relative_imports(tmp_path, source, expect):
    # The check must be able to fail: a simulator module importing discovery is caught.
    path = tmp_path / "mod.py"
    path.write_text(source + "\n")
    targets = [t for _, t in _imports(path, ("vdsbi", "simulator", "mod"))]
    assert any(_package(t) == "discovery" for t in targets) == expect
