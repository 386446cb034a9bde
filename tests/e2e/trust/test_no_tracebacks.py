"""Bad parameters and bad paths for every command: each is a clear `Error: ...` (exit 1, or 2 for
click's own usage errors), never a traceback, and the bank they name is left as it was."""

from __future__ import annotations

import shutil

import pytest
from click.testing import CliRunner

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.errors import BankError
from e2e.trust.corpus import BAD_MANIFESTS, bad_cli_inputs
from support.bankfiles import file_sha256


def make_scratch(root, bank) -> None:
    """The bad places bad_cli_inputs names, under `root`."""
    (root / "afile").write_text("")
    (root / "empty").mkdir()
    (root / "orphan").mkdir()
    shutil.copy(bank / "P09.kuzu", root / "orphan" / "P09.kuzu")
    for name, data in BAD_MANIFESTS.items():
        d = root / f"damaged-{name}"
        d.mkdir()
        (d / "manifest.json").write_bytes(data)


def outcome(result) -> str | None:
    """What is wrong with a run that should have failed cleanly, or None."""
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        return f"traceback: {type(result.exception).__name__}: {result.exception}"
    if result.exit_code not in (1, 2):
        return f"exit code {result.exit_code}"
    if "Error: " not in result.output:
        return "no 'Error: ' line"
    return None


def test_bad_parameters_and_paths_are_clear_errors(small_bank, tmp_path):
    bank = tmp_path / "bank"
    shutil.copytree(small_bank[0], bank)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    make_scratch(scratch, bank)
    before = {p.name: file_sha256(p) for p in bank.iterdir()
              if p.is_file() and p.name != ".verified.json"}  # a read may refresh the integrity check's cache
    cases = bad_cli_inputs(str(bank), str(scratch))
    assert len(cases) >= 250
    bad = {}
    for what, argv in cases:
        problem = outcome(CliRunner().invoke(main, argv))
        if problem:
            bad[what] = problem
    assert bad == {}
    assert {p.name: file_sha256(p) for p in bank.iterdir()
            if p.is_file() and p.name != ".verified.json"} == before
    assert not (scratch / "never").exists()  # no build got as far as making its bank


@pytest.mark.parametrize("name", sorted(BAD_MANIFESTS))
def test_a_damaged_manifest_says_so(tmp_path, name):
    (tmp_path / "manifest.json").write_bytes(BAD_MANIFESTS[name])
    with pytest.raises(BankError, match="manifest"):
        Bank(tmp_path).participants()
