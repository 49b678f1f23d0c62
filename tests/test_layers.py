"""The package's layers: each subpackage imports only from the layers below it (read from the source with ast)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "fastslam_edu"

#: The layers, lowest first; landmark and grid stand side by side (neither imports the other).
ORDER = ("core", "datasets", ("landmark", "grid"), "evaluation", "app")

#: What each layer must not import: every layer above it, and the one beside it. The data layer imports no
#: mapping or evaluation code (its figures would then depend on how they are mapped or scored); nothing below the
#: application imports it.
FORBIDDEN = {
    "core": {"datasets", "landmark", "grid", "evaluation", "app"},
    "datasets": {"landmark", "grid", "evaluation", "app"},
    "landmark": {"grid", "evaluation", "app"},
    "grid": {"landmark", "evaluation", "app"},
    "evaluation": {"app"},
    "app": set(),
}

#: Upward imports still allowed, as (module, layer): none today. An entry goes here only for a module that is being
#: rewritten by someone else, with the comment "left for the engine refactor (issue 30)".
KNOWN_EXCEPTIONS: set[tuple[str, str]] = set()

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


def modules(layer: str) -> list[Path]:
    """Every module of a layer, those of its subpackages included (e.g. ``evaluation/noise_estimation/``)."""
    return sorted((PACKAGE / layer).rglob("*.py"))


def test_the_table_forbids_every_layer_above_and_beside():
    flat = [(i, name) for i, step in enumerate(ORDER) for name in (step if isinstance(step, tuple) else (step,))]
    for i, layer in flat:
        assert FORBIDDEN[layer] == {other for j, other in flat if j >= i and other != layer}, layer


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_layer_imports_only_what_it_may(layer):
    bad = {}
    for p in modules(layer):
        module = str(p.relative_to(PACKAGE))
        wrong = {other for other in imported_layers(p) & FORBIDDEN[layer] if (module, other) not in KNOWN_EXCEPTIONS}
        if wrong:
            bad[module] = sorted(wrong)
    assert not bad, bad


def test_the_known_exceptions_are_still_needed():
    for module, layer in KNOWN_EXCEPTIONS:
        assert layer in imported_layers(PACKAGE / module), f"{module} no longer imports {layer}: drop the exception"


def test_no_layer_has_a_cycle():
    """Reading the imports as a graph of layers: no path from a layer back to itself."""
    graph = {layer: set() for layer in FORBIDDEN}
    for layer in FORBIDDEN:
        for p in modules(layer):
            graph[layer] |= imported_layers(p) - {layer}

    def reaches(start, goal, seen=()):
        return any(nxt == goal or (nxt not in seen and reaches(nxt, goal, seen + (nxt,))) for nxt in graph[start])

    assert not [layer for layer in graph if reaches(layer, layer)]


def test_the_check_sees_an_import_it_forbids(tmp_path):
    source = tmp_path / "m.py"
    source.write_text("import numpy\nfrom fastslam_edu.evaluation.metrics import landmark_errors\n"
                      "def f():\n    from fastslam_edu.app import plotting\n")
    assert imported_layers(source) == {"evaluation", "app"}


def test_the_check_reads_the_modules_of_subpackages():
    found = {str(p.relative_to(PACKAGE)) for p in modules("evaluation")}
    assert "evaluation/noise_estimation/measurement.py" in found
