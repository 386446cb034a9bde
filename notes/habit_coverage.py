"""For the calibration SHabit questions read as "what follows X": does the participant's MEMORA
bank hold a consolidated habit whose trigger is X, and does that habit's next step match the gold
option? Analysis only (it reads gold answers, which the reader never does):

    python notes/habit_coverage.py BANK    # BANK: memora build BANK --participants P01,P02,P03,P04
"""
import sys
from collections import Counter
from memora_graph.retrieve.view import MemoryView
from memora_graph.retrieve.tools import _preference_record
from memora_graph.agent.reading import parse_question, option_items, _is_trigger
from memora_graph.agent.evidence import _preference_events
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.bench.tasks import load_suite

bank = sys.argv[1]
lex = Lexicon.load()
suite = load_suite(None, ["P01", "P02", "P03", "P04"])
rows = Counter()
for pid, entry in suite.participants.items():
    view = MemoryView.open(bank, pid)
    habits = []
    for p in view.preferences.values():
        rec = _preference_record(view, p, None)
        if rec.subtype == "habit":
            habits += [e for e in _preference_events(rec, lex) if e.origin == "habit" and e.follows]
    rows[(pid, "habits in memory")] += len(habits)
    for q in entry.eam_qa.questions:
        q = q.model_dump()
        if q.get("qa_type") != "SHabit" or q.get("is_unanswerable"):
            continue
        intent = parse_question(q["question"], lex)
        if intent.kind != "habit" or intent.trigger is None:
            rows[(pid, "SHabit not read as a habit question")] += 1
            continue
        rows[(pid, "SHabit what-follows-X")] += 1
        trig = intent.trigger
        nouns = set(trig.objects() or trig.nouns) or set(intent.subject_nouns)
        match = [h for h in habits if _is_trigger(h, trig, nouns, lex)]
        if not match:
            rows[(pid, "  no habit with X as trigger")] += 1
            continue
        rows[(pid, "  a habit with X as trigger")] += 1
        gold = q["choices"]["ABCDE".index(q["correct_answer"])] if isinstance(q["choices"], list) else None
        clauses, _ = option_items(gold, intent, lex)
        gitems = {x for c in clauses for x in c}
        nxt = set()
        for h in match:
            for verb, ns in h.follows:
                nxt |= ({("v", verb)} if verb else set()) | {("n", n) for n in ns}
        rows[(pid, "    its next step shares the gold option's verb or object" if gitems & nxt else
              "    its next step shares nothing with the gold option")] += 1
    view.close()
for k in sorted(rows):
    print(k, rows[k])
tot = Counter()
for (p, k), v in rows.items():
    tot[k] += v
print("ALL", dict(tot))
