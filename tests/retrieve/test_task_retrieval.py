"""A routine or preference search returns its top k of the other records as before the task
memory, then at most TASK_EXTRA task-level records: the task rows take no place in the others'
candidate pool or ranks."""

from __future__ import annotations


from memora_graph.consolidate.task_records import TASK_SOURCES
from memora_graph.retrieve.registry import call_tool
from memora_graph.retrieve.search import Candidate
from memora_graph.retrieve.tools import TASK_EXTRA, _reranked
from memora_graph.retrieve.view import MemoryView


def test_each_kind_is_ranked_among_itself_and_cut_to_the_pool():
    cands = {"t1": Candidate("t1", vector_rank=1), "o1": Candidate("o1", vector_rank=2, keyword_rank=3),
             "t2": Candidate("t2", keyword_rank=1), "o2": Candidate("o2", vector_rank=4),
             "o3": Candidate("o3", keyword_rank=5), "o4": Candidate("o4", vector_rank=7)}
    other = _reranked({i: c for i, c in cands.items() if i.startswith("o")}, pool=2)
    assert {i: (c.vector_rank, c.keyword_rank) for i, c in other.items()} == {"o1": (1, 1), "o2": (2, None),
                                                                               "o3": (None, 2)}


def test_task_rows_do_not_crowd_the_other_records_out(small_bank, embedder):
    path, _ = small_bank
    with MemoryView.open(path, "P37", embedder) as view:
        rows = view.preferences
        tasks = {i for i, r in rows.items() if r.get("source") in TASK_SOURCES}
        others = len(rows) - len(tasks)
        assert tasks and others >= 3  # the bundled P37 has both kinds
        view.config = view.config.model_copy(update={"pool": 3})  # a pool the task rows alone could fill
        for query in ("one at a time", "before washing it", "staging spot between steps"):
            prefs = call_tool(view, "get_preferences", {"query": query, "top_k": 3}).preferences
            kinds = [p.preference_id in tasks for p in prefs]
            assert kinds == sorted(kinds)  # the others first, then the task records
            assert kinds.count(False) == 3 and kinds.count(True) <= TASK_EXTRA, query
