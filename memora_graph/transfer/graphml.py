"""A participant's memory as a networkx graph, written as GraphML (Gephi, Cytoscape, yEd, networkx).

GraphML attributes are scalars: lists become JSON strings, times ISO strings, and a missing
value is left out. Every node carries its table as `type` and a readable `label`; every edge
its table as `type`. Embeddings are left out unless asked for (384 floats per node, as a JSON string).
"""

from __future__ import annotations

import json
import os
from collections import Counter
from datetime import datetime
from pathlib import Path

import networkx as nx

from memora_graph.transfer.dump import ParticipantDump

# the property that names a node, per table (else its id)
LABELS = {"Video": "id", "Segment": "summary", "Place": "name", "Entity": "name", "StateEvent": "state",
          "EditOp": "op", "Routine": "goal", "Preference": "statement", "ModelCall": "role"}


def _scalar(value):
    if isinstance(value, list):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, datetime):
        return value.isoformat()
    return value


def to_graph(dump: ParticipantDump, embeddings: bool = False) -> nx.MultiDiGraph:
    """Nodes keyed by id (`Table:id` where two tables share an id); parallel edges kept."""
    g = nx.MultiDiGraph(participant=dump.participant, embed_model=dump.bank["embed_model"], mode=dump.bank["mode"])
    seen = Counter(i for t in dump.nodes() for i in t.frame["id"].to_list())
    key = {}
    for t in dump.nodes():
        skip = set() if embeddings else {c for c, typ in t.columns if typ.startswith("FLOAT[")}
        for row in t.frame.rows(named=True):
            k = row["id"] if seen[row["id"]] == 1 else f"{t.name}:{row['id']}"
            key[(t.name, row["id"])] = k
            attrs = {c: _scalar(v) for c, v in row.items() if v is not None and c not in skip}
            label = row.get(LABELS.get(t.name, "id")) or row["id"]
            g.add_node(k, **{**attrs, "type": t.name, "label": str(label)[:80]})
    for t in dump.rels():
        for row in t.frame.rows(named=True):
            attrs = {c: _scalar(v) for c, v in row.items() if v is not None and c not in ("from", "to")}
            g.add_edge(key[(t.from_table, row["from"])], key[(t.to_table, row["to"])], **{**attrs, "type": t.name})
    return g


def write_graphml(dump: ParticipantDump, out: Path, embeddings: bool = False) -> Path:
    tmp = out.with_name(f".{out.name}.tmp")
    try:
        nx.write_graphml(to_graph(dump, embeddings), tmp)
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out
