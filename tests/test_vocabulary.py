"""One vocabulary (issue 30, item 5): one name per function, and the book's letters in the docstrings' shapes.

* No top-level function name is defined in two modules of fastslam_edu (read with ast): two functions of one name
  make a reader, and an import, pick the wrong one. ``KNOWN_DUPLICATES`` lists those left, each with who keeps it
  and why; a test says when an entry is no longer a duplicate. (A re-export alias, ``old = new``, is an
  assignment, not a definition: the old name of a renamed function may stay for callers not yet moved.)
* One suffix rule for a concept written twice (the package docstring): the teaching form (numpy) has the plain
  name, its compiled twin (numba) the same name plus ``_kernel``. Read with ast: every ``*_kernel`` is compiled
  and has a teaching form of its stem; no compiled function has the name of a teaching function; a compiled
  function whose docstring opens with ``:func:`stem``` (the teaching function it is the twin of) is ``stem_kernel``.
* The landmark count is :math:`N` and :math:`K` only ever the Kalman gain (``book/notation.md``): no docstring or
  comment of the package gives a shape with a ``K`` axis — ``(K,)``, ``(K, 2)``, ``(M, K, 2)``, ``(n, K)``.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "fastslam_edu"

#: Top-level function names still defined in more than one module, each with why it is left (by name only: the
#: modules that hold them are being split in issue 30).
KNOWN_DUPLICATES: set[str] = {
    "main",  # python -m entry points (``python -m fastslam_edu.datasets.fetch`` ...): the conventional name, kept
    "propagate",  # core.motion's is the deterministic g(x, u); landmark/particle_set.py's samples step 1 (its owner)
}

#: A shape with a K axis: ``(K,)``, ``(K, 2)``, ``(K,2,2)``, ``(M, K, 2)``, ``(n, K)`` ... (a tuple: with a comma; ``(K)``
#: alone names the gain)
K_SHAPE = re.compile(r"\((?:\s*\w+\s*,)*\s*K\s*(?:,\s*\w*\s*)*\)")


def modules() -> dict[str, str]:
    """Source of every module of the package, by path relative to it (``core/se2.py``)."""
    return {p.relative_to(PACKAGE).as_posix(): p.read_text(encoding="utf-8") for p in sorted(PACKAGE.rglob("*.py"))}


def duplicate_names(sources: dict[str, str]) -> dict[str, set[str]]:
    """Top-level function names (``def`` at module level) defined in more than one module, with their modules."""
    where = defaultdict(set)
    for path, source in sources.items():
        for node in ast.parse(source).body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                where[node.name].add(path)
    return {name: paths for name, paths in where.items() if len(paths) > 1}


def compiled(node: ast.FunctionDef) -> bool:
    """Whether a ``def`` is decorated with numba's ``njit``/``jit`` (``@njit``, ``@njit(...)``, ``@numba.njit(...)``)."""
    for decorator in node.decorator_list:
        f = decorator.func if isinstance(decorator, ast.Call) else decorator
        if (f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")) in {"njit", "jit"}:
            return True
    return False


def public_functions(sources: dict[str, str]) -> list[tuple[str, ast.FunctionDef]]:
    """``(path, node)`` of every public top-level ``def`` (no leading underscore) of the modules."""
    return [(path, node) for path, source in sources.items() for node in ast.parse(source).body
            if isinstance(node, ast.FunctionDef) and not node.name.startswith("_")]


def kernel_rule_breaches(sources: dict[str, str]) -> set[str]:
    """``"path: name: what"`` for each breach of the suffix rule (module docstring) in ``sources``."""
    functions = public_functions(sources)
    teaching = {node.name for _, node in functions if not compiled(node)}
    breaches = set()
    for path, node in functions:
        name, is_compiled = node.name, compiled(node)
        if name.endswith("_kernel"):
            if not is_compiled:
                breaches.add(f"{path}: {name}: not compiled")
            if name.removesuffix("_kernel") not in teaching:
                breaches.add(f"{path}: {name}: no teaching form {name.removesuffix('_kernel')}")
        elif is_compiled and name in teaching:
            breaches.add(f"{path}: {name}: compiled, with the name of a teaching function")
        elif is_compiled:
            twin = re.match(r":func:`~?([\w.]+)`", ast.get_docstring(node) or "")
            stem = twin.group(1).rsplit(".", 1)[-1] if twin else None
            if stem in teaching:
                breaches.add(f"{path}: {name}: the twin of {stem}, so {stem}_kernel")
    return breaches


def prose(source: str) -> list[tuple[int, str]]:
    """``(line, text)`` of every docstring (module, class, function) and comment of a module's source."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                out.append((first.lineno, first.value.value))
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            out.append((tok.start[0], tok.string))
    return out


def k_shapes(source: str) -> list[tuple[int, str]]:
    """``(line, match)`` of every shape with a K axis in the docstrings and comments of ``source``."""
    return [(line, m.group()) for line, text in prose(source) for m in K_SHAPE.finditer(text) if "," in m.group()]


# ---------------------------------------------------------------- the checks read what they should


def test_duplicate_names_on_a_small_package():
    sources = {
        "a.py": "def f():\n    pass\n\ndef g():\n    def h():\n        pass\n",
        "b.py": "class C:\n    def g(self):\n        pass\n\ndef f():\n    pass\n\nh = f\n",
        "c.py": "async def f():\n    pass\n",
    }
    # methods, nested functions and aliases are not definitions at module level
    assert duplicate_names(sources) == {"f": {"a.py", "b.py", "c.py"}}


def test_kernel_rule_on_a_small_package():
    sources = {
        "a.py": "from numba import njit\n\ndef wrap(a):\n    pass\n\n@njit(cache=True)\ndef wrap_kernel(a):\n"
                "    return a\n\n@njit\ndef run(a):\n    pass\n\ndef _private_kernel():\n    pass\n",
        "b.py": "def lonely_kernel(a):\n    pass\n",  # not compiled, and no teaching form ``lonely``
        "c.py": "@njit\ndef orphan_kernel(a):\n    pass\n",  # compiled, no teaching form ``orphan``
        "d.py": "import numba\n\n@numba.njit(cache=True)\ndef wrap(a):\n    pass\n",  # the teaching name, compiled
        "e.py": '@njit\ndef wrap_scalar(a):\n    """:func:`a.wrap` of one angle."""\n',  # a twin without the suffix
    }
    assert kernel_rule_breaches(sources) == {
        "b.py: lonely_kernel: not compiled", "b.py: lonely_kernel: no teaching form lonely",
        "c.py: orphan_kernel: no teaching form orphan",
        "d.py: wrap: compiled, with the name of a teaching function",
        "e.py: wrap_scalar: the twin of wrap, so wrap_kernel",
    }
    assert not kernel_rule_breaches({"a.py": sources["a.py"]})


def test_k_shapes_in_docstrings_and_comments_only():
    source = (
        '"""Map (K, 2) and (K,) counts; the gain K (2, 2); shape (..., K)."""\n'
        "x = '(K, 2)'  # mu (K,2,2) per landmark\n"
        "def f():\n"
        '    """``sigma`` (N, 2, 2), ``gain`` (K, 2)"""\n'
        "    return (K, 2)\n"
    )
    assert k_shapes(source) == [(1, "(K, 2)"), (1, "(K,)"), (4, "(K, 2)"), (2, "(K,2,2)")]
    assert k_shapes('"""landmarks (N, 2), gain K = Σ Hᵀ Q⁻¹ (2, 2)"""\n') == []
    assert k_shapes('"""mu (M, K, 2), ll (n, K), cov (M, N, 2, 2), gain (K)"""\n') == [(1, "(M, K, 2)"), (1, "(n, K)")]


# ---------------------------------------------------------------- the package


def test_no_function_name_in_two_modules():
    found = duplicate_names(modules())
    new = {name: sorted(paths) for name, paths in found.items() if name not in KNOWN_DUPLICATES}
    assert not new, f"one name, two functions (rename one to say what it computes): {new}"


def test_kernel_suffix_rule():
    """The teaching form has the plain name, its compiled twin ``_kernel`` (fastslam_edu's docstring)."""
    breaches = kernel_rule_breaches(modules())
    assert not breaches, f"one suffix rule, ``name`` and ``name_kernel`` (fastslam_edu/__init__.py): {sorted(breaches)}"
    kernels = {node.name for _, node in public_functions(modules()) if node.name.endswith("_kernel")}
    assert {"update_landmark_kernel", "wrap_angle_kernel", "tempering_exponents_kernel"} <= kernels


@pytest.mark.parametrize("name", sorted(KNOWN_DUPLICATES))
def test_every_known_duplicate_is_still_one(name):
    assert name in duplicate_names(modules()), f"{name} is defined in one module now: drop it from KNOWN_DUPLICATES"


def test_no_landmark_shape_with_k():
    found = {path: k_shapes(source) for path, source in modules().items()}
    found = {path: hits for path, hits in found.items() if hits}
    assert not found, f"the landmark count is N, K the Kalman gain (book/notation.md): {found}"


# ---------------------------------------------------------------- one three-way choice, one name


def test_association_is_one_three_way_choice():
    """``AssociationParams.association`` ("joint" | "greedy" | "independent") replaced the two flags ``exclusive``
    and ``joint_compatibility``, which encoded one choice in four combinations; the kernels' ``Rules`` carry it as
    one code too, and a name that is not a rule is refused by name."""
    import dataclasses

    from fastslam_edu.landmark.association_params import ASSOCIATION_RULES, AssociationParams, Rules

    names = {f.name for f in dataclasses.fields(AssociationParams)}
    assert "association" in names and not names & {"exclusive", "joint_compatibility"}
    assert not set(Rules._fields) & {"exclusive", "joint", "joint_compatibility"}
    assert set(ASSOCIATION_RULES) == {"joint", "greedy", "independent"}
    assert len(set(ASSOCIATION_RULES.values())) == 3  # three codes for three rules
    assert AssociationParams().association == "joint"
    for name, code in ASSOCIATION_RULES.items():
        assert AssociationParams(association=name).rules().association == code
    with pytest.raises(ValueError, match="'exclusive'"):
        AssociationParams(association="exclusive")


def test_the_cli_association_option_takes_the_three_rules():
    from fastslam_edu.app.cli import build_parser
    from fastslam_edu.landmark.association_params import ASSOCIATION_RULES

    parser = build_parser()
    base = ["run", "--data", ".", "--robot", "1", "--correspondences", "unknown"]
    for name in ASSOCIATION_RULES:
        assert parser.parse_args([*base, "--association", name]).association == name
    assert parser.parse_args(base).association is None  # AssociationParams' default then
    with pytest.raises(SystemExit):
        parser.parse_args([*base, "--association", "exclusive"])


def test_one_name_for_the_tempering_exponent():
    """β is the tempering exponent: ``tempering_exponents`` the teaching form (returns β), ``tempering_exponents_kernel``
    its compiled twin (writes β), the same numbers; the old name ``evidence_fractions`` is gone."""
    import numpy as np

    from fastslam_edu.landmark import evidence

    assert not hasattr(evidence, "evidence_fractions")
    last = np.array([10.0, -np.inf, 18.0])
    beta = np.empty(3)
    evidence.tempering_exponents_kernel(19.0, np.array([0, 1, 2]), last.copy(), 4.0, beta)
    np.testing.assert_array_equal(evidence.tempering_exponents(19.0, [0, 1, 2], last.copy(), 4.0), beta)
    np.testing.assert_array_equal(beta, [1.0, 1.0, 0.25])  # min(1, Δt/τ): Δt 9 s, never seen, 1 s
