"""The package's layers: each subpackage imports only from the layers below it (read from the source with ast)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "fastslam_edu"

#: What each layer must not import. The data layer imports no evaluation code (its figures would then depend on
#: how they are scored); nothing below the application imports it.
FORBIDDEN = {
    "core": {"datasets", "landmark", "grid", "evaluation", "app"},
    "datasets": {"landmark", "evaluation", "app"},
    "landmark": {"app"},
    "grid": {"app"},
    "evaluation": {"app"},
    "app": set(),
}


def imported_layers(path: Path) -> set[str]:
    """The fastslam_edu subpackages a module imports (absolute imports, as the package writes them)."""
    layers = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "fastslam_edu" and len(parts) > 1:
                layers.add(parts[1])
    return layers


def test_every_module_lives_in_a_layer():
    assert sorted(p.name for p in PACKAGE.glob("*.py")) == ["__init__.py"]
    assert {p.name for p in PACKAGE.iterdir() if p.is_dir() and not p.name.startswith("__")} == set(FORBIDDEN)


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_layer_imports_only_what_it_may(layer):
    bad = {f"{p.relative_to(PACKAGE)}: {sorted(imported_layers(p) & FORBIDDEN[layer])}"
           for p in (PACKAGE / layer).glob("*.py") if imported_layers(p) & FORBIDDEN[layer]}
    assert not bad, bad


def test_the_check_sees_an_import_it_forbids(tmp_path):
    source = tmp_path / "m.py"
    source.write_text("import numpy\nfrom fastslam_edu.evaluation.metrics import landmark_errors\n"
                      "def f():\n    from fastslam_edu.app import plotting\n")
    assert imported_layers(source) == {"evaluation", "app"}
