"""A folder's files written aside and moved into place together (noise and synth annotation sets)."""

from __future__ import annotations

import pytest

from memora_graph.files import staged_files


def test_files_appear_together_and_a_failed_block_leaves_the_folder_as_it_was(tmp_path):
    out = tmp_path / "set"
    with staged_files(out) as aside:
        aside("a.csv").write_text("1\n")
        aside("b.json").write_text("{}\n")
        assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == []  # nothing in place yet
    assert sorted(p.name for p in out.iterdir()) == ["a.csv", "b.json"]
    with pytest.raises(RuntimeError):
        with staged_files(out) as aside:
            aside("a.csv").write_text("2\n")
            raise RuntimeError("the writer failed")
    assert sorted(p.name for p in out.iterdir()) == ["a.csv", "b.json"] and (out / "a.csv").read_text() == "1\n"
