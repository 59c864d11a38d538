"""Lower layers never import higher ones (docs: ARCHITECTURE layering rule)."""

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FORBIDDEN = {
    "carlo_lite": {"scenarios", "predictor", "pipeline", "tools", "benchmarks", "torch", "h5py"},
    "scenarios": {"predictor", "pipeline", "tools", "benchmarks", "torch", "h5py"},
    "predictor": {"carlo_lite", "scenarios", "pipeline", "tools", "benchmarks"},
    "pipeline": {"tools", "benchmarks"},
}


def imported_top_level_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_imports_respect_layers(package):
    files = sorted((REPO / package).rglob("*.py"))
    assert files, f"package {package} has no modules"
    violations = {
        str(path.relative_to(REPO)): sorted(imported_top_level_modules(path) & FORBIDDEN[package])
        for path in files
    }
    assert {k: v for k, v in violations.items() if v} == {}


def test_format_module_does_not_need_torch():
    assert "torch" not in imported_top_level_modules(REPO / "predictor" / "format.py")
