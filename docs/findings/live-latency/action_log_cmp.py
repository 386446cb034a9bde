"""The typed reader's action log read by an earlier version of agent/open_answer.py and by this
one, on the same rows: equal steps, and each one's CPU time.
usage: git show REV:memora_graph/agent/open_answer.py > /tmp/old_open_answer.py
       PYTHONPATH=. python docs/findings/live-latency/action_log_cmp.py BANK P01 /tmp/old_open_answer.py"""
import dataclasses
import importlib.util
import sys
import time

from memora_graph.agent.query import log as new  # the action log moved here from agent/open_answer.py
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.view import MemoryView

bank, participant, old_file = sys.argv[1:4]
spec = importlib.util.spec_from_file_location("old_open_answer", old_file)
old = importlib.util.module_from_spec(spec)
sys.modules["old_open_answer"] = old
spec.loader.exec_module(old)
lex = Lexicon.load()
with MemoryView.open(bank, participant) as view:
    rows = view.fetch("_open_action_log")
    c0 = time.process_time()
    a = [s for seg in rows for s in old._segment_steps(seg, lex)]
    c1 = time.process_time()
    seen: dict = {}
    b = [s for seg in rows for s in new._segment_steps(seg, lex, seen)]
    c2 = time.process_time()
    same = [dataclasses.astuple(s) for s in a] == [dataclasses.astuple(s) for s in b]
    print(f"steps {len(a)} equal {same} old {c1 - c0:.2f} new {c2 - c1:.2f} CPU-s, distinct wordings {len(seen)}")
