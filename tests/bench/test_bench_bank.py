"""MEMORA-Bench Replay grounding reads the bank's object registry and nothing else."""

import json

from click.testing import CliRunner

from memora_graph.bank import Bank
from memora_graph.cli import main


def test_generate_grounds_replay_nouns_in_the_bank_registry(small_bank, tmp_path):
    path, _ = small_bank
    registry = Bank(path).object_registries(["P37"])["P37"]
    assert registry and all(r["memory_id"] and r["location"] for r in registry)
    out = tmp_path / "suite"
    r = CliRunner().invoke(main, ["bench", "generate", "--out", str(out), "--participants", "P37",
                                  "--bank", str(path), "--no-dedup"])
    assert r.exit_code == 0, r.output
    tasks = json.loads((out / "planning/suites/replay/p37.json").read_text())
    grounded = [s for t in tasks for s in t["ground_truth_steps"] if "matched_object" in s]
    assert grounded, "no Replay step was grounded in the bank"
    ids = {x["memory_id"] for x in registry}
    assert all(s["matched_object"]["memory_id"] in ids for s in grounded)
