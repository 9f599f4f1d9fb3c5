r'''The floors of the tree: no module imports from a floor above its own

reference_models < targets < renderers < harness < reports < camval (the command line).
Data flows up: a camera model knows nothing of boards, a board nothing of renderers,
a renderer nothing of campaigns, a campaign nothing of its report, and only the
command line knows them all. Every import statement counts, at module level or
inside a function (a lazy import is still a dependency).
'''
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
FLOORS = ("reference_models", "targets", "renderers", "harness", "reports", "camval")


def _imports(path):
    r'''Top-level package names imported by a file (relative imports stay in their package)'''
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.lineno, node.module.split(".")[0]


def _violations():
    out = []
    for floor, package in enumerate(FLOORS):
        for path in sorted((ROOT / package).rglob("*.py")):
            for lineno, name in _imports(path):
                if name in FLOORS and FLOORS.index(name) > floor:
                    out.append(f"{path.relative_to(ROOT)}:{lineno} imports {name} "
                               f"(floor {FLOORS.index(name)} above {package}, floor {floor})")
    return out


def test_no_import_reaches_a_higher_floor():
    assert _violations() == []


def test_figures_are_drawn_only_in_reports():
    drawers = [f"{path.relative_to(ROOT)}:{lineno}"
               for package in FLOORS if package != "reports"
               for path in sorted((ROOT / package).rglob("*.py"))
               for lineno, name in _imports(path) if name == "matplotlib"]
    assert drawers == []


def test_the_check_sees_lazy_imports(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import numpy\ndef f():\n    from harness.runner import run_job\n"
                 "    import reports.build\nfrom . import x\n")
    assert [n for _, n in _imports(f)] == ["numpy", "harness", "reports"]


@pytest.mark.parametrize("package", FLOORS)
def test_every_floor_exists(package):
    assert (ROOT / package / "__init__.py").exists()
