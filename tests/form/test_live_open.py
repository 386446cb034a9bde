"""What a live writer reads when it opens (form/live.py `_load`): the editor's registry read as
columns gives the entities the whole-node read gave, field for field and vector for vector."""

from __future__ import annotations

import numpy as np

from memora_graph import schema
from memora_graph.bank import Bank
from memora_graph.form.build import load_entities
from memora_graph.form.editor import EntityState
from memora_graph.form.live import LiveWriter, Moment
from memora_graph.store import Store


def _whole_nodes(store: Store, participant: str) -> list[EntityState]:
    """The registry as it was read before: each entity's whole node, row by row."""
    out = []
    for r in store.query("MATCH (e:Entity) WHERE e.participant = $p RETURN e AS entity ORDER BY e.id",
                         {"p": participant}).to_dicts():
        r = r["entity"]
        e = EntityState(**{k: (r[k] if r[k] is not None else "") for k in schema.columns("Entity", emb=False)})
        e.emb = np.asarray(r["emb"], dtype=np.float32) if r.get("emb") is not None else None
        out.append(e)
    return out


def _same(a: list[EntityState], b: list[EntityState]) -> None:
    assert [e.id for e in a] == [e.id for e in b]
    for x, y in zip(a, b):
        for k in schema.columns("Entity", emb=False):
            assert (getattr(x, k), type(getattr(x, k))) == (getattr(y, k), type(getattr(y, k))), (x.id, k)
        assert (x.emb is None) == (y.emb is None), x.id
        assert x.emb is None or x.emb.tobytes() == y.emb.tobytes(), x.id


def test_the_registry_read_as_columns_is_the_registry_read_as_nodes(tmp_path):
    bank = tmp_path / "bank"
    with LiveWriter(bank, "P01") as memory:
        for i, text in enumerate(["take the cup from the cupboard", "put the cup in the sink",
                                  "open the fridge and take the milk", "wash the knife"]):
            memory.remember(Moment("home-1", 3.0 * i, 3.0 * i + 2.0, text))
        # an entity with columns left NULL and no vector (a row another writer left so): "" and None
        memory.store.query("CREATE (:Entity {id: 'P01:odd', participant: 'P01', object_id: 'odd', kind: 'object', "
                           "name: 'odd'})")
    with Store(Bank(bank).db_path("P01"), read_only=True) as store:
        want, got = _whole_nodes(store, "P01"), load_entities(store, "P01")
        assert len(got) >= 4 and any(e.emb is not None for e in got)
        odd = next(e for e in got if e.id == "P01:odd")
        assert odd.emb is None and odd.color == "" and odd.first_seen == "" and odd.is_fixture == ""
        _same(want, got)
        assert load_entities(store, "P02") == []


def test_a_reopened_writer_edits_the_entities_it_remembered(tmp_path):
    """The registry a reopened writer holds is the one it wrote: the cup is found again (an
    UPDATE of the same entity, by its vector and name), not added twice."""
    bank = tmp_path / "bank"
    with LiveWriter(bank, "P01") as memory:
        first = memory.remember(Moment("home-1", 0.0, 2.0, "take the cup from the cupboard"))
        cup = next(o["entity"] for o in first.ops if o["object"] == "cup")
        before = {e.id: e for e in memory.editor.entities.values()}
    with LiveWriter(bank, "P01") as memory:
        _same(sorted(before.values(), key=lambda e: e.id), sorted(memory.editor.entities.values(), key=lambda e: e.id))
        again = memory.remember(Moment("home-1", 5.0, 6.0, "put the cup in the sink"))
        assert any(o["op"] == "UPDATE" and o["entity"] == cup for o in again.ops)
        assert not any(o["op"] == "ADD" and o["object"] == "cup" for o in again.ops)
