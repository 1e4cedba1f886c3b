"""Imports that keep test-only code and the seeding apart from the pipeline stages."""

import ast

from helpers import ROOT

PACKAGE = ROOT / "mitsuforest"


def _imported(path) -> set[str]:
    """The absolute names of the modules ``path`` imports (relative imports resolved)."""
    package = ".".join(path.relative_to(ROOT).parent.parts)
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            stem = ".".join(p for p in (base, node.module) if p)
            names |= {stem} | {f"{stem}.{a.name}" for a in node.names}
    return names


def test_no_module_of_the_package_imports_the_testing_code():
    outside = [p for p in PACKAGE.rglob("*.py") if "testing" not in p.relative_to(PACKAGE).parts]
    found = {str(p.relative_to(ROOT)): sorted(n for n in _imported(p) if n.startswith("mitsuforest.testing"))
             for p in outside}
    assert {k: v for k, v in found.items() if v} == {}
    # the check sees the package's relative imports
    assert "mitsuforest.testing.reference.pulses" in _imported(PACKAGE / "testing" / "analytic.py")


def test_the_seeding_module_imports_no_part_of_the_package():
    assert {n for n in _imported(PACKAGE / "seeds.py") if n.startswith("mitsuforest")} == set()
    assert "mitsuforest.seeds" in _imported(PACKAGE / "plan" / "__init__.py")
