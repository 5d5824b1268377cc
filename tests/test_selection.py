"""Which tests run by default: every unit test and the representative integration tests named in
tests/conftest.py REPRESENTATIVE; the other integration tests and the slow ones are opt-in."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

from tests.conftest import REPRESENTATIVE

ROOT = Path(__file__).resolve().parents[1]


def _marks(decorators: list[ast.expr]) -> set[str]:
    """Names of the pytest.mark.NAME decorators (or of a module's pytestmark)."""
    names = set()
    for node in decorators:
        node = node.func if isinstance(node, ast.Call) else node
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Attribute)
            and node.value.attr == "mark"
        ):
            names.add(node.attr)
    return names


def _test_marks(path: Path, name: str) -> set[str] | None:
    """The marks on test function `name` in path (module-wide ones included); None if it is not there."""
    tree = ast.parse(path.read_text())
    module: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "pytestmark" for t in node.targets):
            values = node.value.elts if isinstance(node.value, ast.List | ast.Tuple) else [node.value]
            module |= _marks(values)
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name == name:
            return module | _marks(node.decorator_list)
    return None


def test_each_representative_names_an_integration_test_that_is_not_slow() -> None:
    assert 4 <= len(REPRESENTATIVE) == len(set(REPRESENTATIVE)) <= 6
    for node_id in REPRESENTATIVE:
        file, name = node_id.split("::")
        marks = _test_marks(ROOT / file, name)
        assert marks is not None, f"{node_id}: no such test"
        assert "integration" in marks and "slow" not in marks, (node_id, marks)


def test_the_default_selection_takes_the_representatives_and_leaves_the_other_integration_tests() -> None:
    files = ["tests/verifier/test_sfm.py", "tests/daemon/protect/test_quarantine.py"]  # each has both kinds
    env = {**os.environ, "PYTHONPATH": str(ROOT)}

    def collected(*options: str) -> set[str]:
        command = [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider"]
        proc = subprocess.run(
            [*command, *options, *files], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        return {line.split("[", 1)[0] for line in proc.stdout.splitlines() if "::" in line}

    default, everything = collected(), collected("-m", "")
    integration = collected("-m", "integration")
    wanted = {n for n in REPRESENTATIVE if n.split("::")[0] in files}
    assert wanted and wanted <= default and wanted <= integration
    assert default & integration == wanted  # no other integration test by default
    assert default == everything - integration | wanted  # every unit test by default
