"""The test suite mirrors the package: tests/<pkg>/ holds the tests of memora_graph/<pkg>/ (a
sub-folder the tests of its sub-package), tests/base/ those of the package's root modules, tests/e2e/
the end-to-end and opt-in groups, tests/support/ the shared helpers; no test module sits loose in
tests/, and the opt-in groups selected by marker (`-m ray`, `-m real_model`) are exactly their folders."""

from __future__ import annotations

import re
from pathlib import Path

import memora_graph

TESTS = Path(__file__).resolve().parents[1]
PACKAGE = Path(memora_graph.__file__).parent
EXTRAS = {"base", "e2e", "support"}  # not packages: the root modules, the end-to-end groups, the helpers
E2E_GROUPS = {"trust", "video", "ray", "real_model"}
MARKED_GROUPS = ("ray", "real_model")  # a module-wide `pytestmark = pytest.mark.<group>` lives in e2e/<group>/


def _folders(root: Path) -> list[Path]:
    return sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith((".", "__")))


def _unmirrored(tests_dir: Path, package_dir: Path) -> list[str]:
    """Folders under `tests_dir` that name no package under `package_dir`, recursively."""
    wrong = []
    for folder in _folders(tests_dir):
        if tests_dir == TESTS and folder.name in EXTRAS:
            continue
        mirror = package_dir / folder.name
        if (mirror / "__init__.py").is_file():
            wrong += _unmirrored(folder, mirror)
        else:
            wrong.append(str(folder.relative_to(TESTS)))
    return wrong


def test_every_test_folder_names_a_package():
    wrong = _unmirrored(TESTS, PACKAGE)
    packages = sorted(p.name for p in _folders(PACKAGE) if (p / "__init__.py").is_file())
    assert not wrong, (f"test folders that name no package of memora_graph/: {wrong}; a folder is a package "
                       f"({', '.join(packages)}) or one of {sorted(EXTRAS)}")


def test_e2e_holds_only_the_end_to_end_groups():
    groups = {f.name for f in _folders(TESTS / "e2e")}
    assert groups <= E2E_GROUPS, f"tests/e2e/ holds {sorted(groups - E2E_GROUPS)}; its groups are {sorted(E2E_GROUPS)}"


def test_no_test_module_sits_loose_in_tests():
    loose = sorted(p.name for p in TESTS.glob("*.py") if p.name != "conftest.py")
    assert not loose, f"test modules directly in tests/ (put each in the folder of the package it tests): {loose}"


def test_marked_groups_are_their_folders():
    for group in MARKED_GROUPS:
        marked = re.compile(rf"^pytestmark\s*=.*\bpytest\.mark\.{group}\b", re.M)
        home = TESTS / "e2e" / group
        for path in TESTS.rglob("test_*.py"):
            inside = home in path.parents
            assert bool(marked.search(path.read_text())) == inside, (
                f"{path.relative_to(TESTS)}: the `{group}` group's modules are marked `pytest.mark.{group}` "
                f"and live in tests/e2e/{group}/")
