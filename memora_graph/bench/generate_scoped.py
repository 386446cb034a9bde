"""Open questions that combine a scope, a selector and a relation with an operation, gold from the
annotations (`generate_open` adds them to its items).

Kinds (operation x scope):

- count_video      how many times an action happened in one video (count x video)
- yes_video        whether it happened in a video where it did (exists x video)
- no_video         ... in a video where it did not, though it did in another (exists x video)
- place_video      where the object was last put in one video (where x video)
- last_in_video    the last thing done in a video (list x video, selector last), scored at verb + noun class
- first_in_video   the first thing done in a video (list x video, selector first)
- first_in_session the first thing done in the person's last / nth session (list x session)
- count_window     how many times in a time window of a video (count x window)
- count_after      how many times in a video after an event there (count x event)
- previous         what usually comes just before an action (previous x all, relation before)
- time_nth         the video of the second / third time an action happened (which_video x all, selector nth)

Wordings vary in person (third person "P04", first person "I" for the memory's owner), voice
(passive), spelling (a letter dropped from the object's name) and ellipsis (a second question
that only changes the scope: "... in P01_102? And in P01_103?"). Items of one template that
differ only in their scope share a `pair` id: the counterfactual check (`open_eval`) asks that
their answers differ wherever their gold does.
"""

from __future__ import annotations

import random
from collections import Counter

from memora_graph.bench.behaviour import PUT_VERB_KEYS, ActionClass, Behaviour, noun_text, past

SCOPED_SPLITS = ("third", "me")  # the wording's person: "P04 ..." or "I ..." (the memory's owner)
SCOPED_KINDS = ("count_video", "yes_video", "no_video", "place_video", "last_in_video", "first_in_video",
                "first_in_session", "count_window", "count_after", "previous", "time_nth")
PER_SCOPED = {"count_video": 6, "yes_video": 6, "no_video": 6, "place_video": 6, "last_in_video": 6,
              "first_in_video": 6, "first_in_session": 3, "count_window": 6, "count_after": 5, "previous": 8,
              "time_nth": 5}
# kind -> (operation, scope) cell
CELLS = {"count_video": ("count", "video"), "yes_video": ("exists", "video"), "no_video": ("exists", "video"),
         "place_video": ("where", "video"), "last_in_video": ("list", "video"), "first_in_video": ("list", "video"),
         "first_in_session": ("list", "session"), "count_window": ("count", "window"),
         "count_after": ("count", "event"), "previous": ("previous", "all"), "time_nth": ("which_video", "all"),
         "place_last": ("where", "all"), "place_usual": ("where", "all"), "time_last": ("which_video", "all"),
         "time_first": ("which_video", "all"), "count": ("count", "all"), "yes": ("exists", "all"),
         "no": ("exists", "all"), "next": ("next", "all"), "absent": ("not_in_memory", "all"),
         "general": ("world", "all")}

# {P} person (or "I"), {V} video, {o} object, {b} base verb, {p} past, {n} participle, {a} {z} clock times,
# {e} the event's past ("opened the fridge"), {N} ordinal; "me" forms are the first person ("I", the owner)
SCOPED_TEMPLATES: dict[str, dict[str, list[str]]] = {
    "count_video": {
        "third": ["How many times did {P} {b} the {o} in video {V}?", "In {V}, how often did {P} {b} the {o}?",
                  "Count the times the {o} was {n} in {V}."],
        "me": ["How many times did I {b} the {o} in {V}?", "How often did I {b} the {o} during {V}?"],
    },
    "yes_video": {
        "third": ["Did {P} {b} the {o} in {V}?", "In video {V}, did {P} {b} the {o}?",
                  "Was the {o} {n} in {V}?"],
        "me": ["Did I {b} the {o} in {V}?", "In {V}, did I {b} the {o} at all?"],
    },
    "place_video": {
        "third": ["Where did {P} last put the {o} in {V}?", "In {V}, where did {P} put the {o} the last time?"],
        "me": ["Where did I last put the {o} in {V}?", "In video {V}, where did I leave the {o} last?"],
    },
    "last_in_video": {
        "third": ["What was the last thing {P} did in {V}?", "What did {P} do last in video {V}?"],
        "me": ["What was the last thing I did in {V}?", "What was my final action in {V}?"],
    },
    "first_in_video": {
        "third": ["What was the first thing {P} did in {V}?", "In {V}, what did {P} do first?"],
        "me": ["What was the first thing I did in {V}?", "What did I do first in video {V}?"],
    },
    "first_in_session": {
        "third": ["What was the first thing {P} did in their last video?",
                  "What did {P} do first in their {N} session?"],
        "me": ["What was the first thing I did in my last video?", "What did I do first in my {N} session?"],
    },
    "count_window": {
        "third": ["How many times did {P} {b} the {o} in {V} between {a} and {z}?",
                  "Between {a} and {z} of {V}, how often did {P} {b} the {o}?"],
        "me": ["How many times did I {b} the {o} in {V} between {a} and {z}?"],
    },
    "count_after": {
        "third": ["In {V}, how many times did {P} {b} the {o} after they {e}?"],
        "me": ["How many times did I {b} the {o} in {V} after I {e}?"],
    },
    "previous": {
        "third": ["What does {P} usually do just before they {b} the {o}?",
                  "Before {P} {s} the {o}, what do they usually do?",
                  "What usually comes right before {P} {s} the {o}?"],
        "me": ["What do I usually do just before I {b} the {o}?", "What do I normally do right before I {b} the {o}?"],
    },
    "time_nth": {
        "third": ["In which video did {P} {b} the {o} for the {N} time?", "Which recording shows the {N} time {P} "
                  "{p} the {o}?"],
        "me": ["In which video did I {b} the {o} for the {N} time?"],
    },
}
SCOPED_TEMPLATES["no_video"] = SCOPED_TEMPLATES["yes_video"]
_ORD = {1: "first", 2: "second", 3: "third", 4: "fourth", 5: "fifth"}


def _clock(seconds: float) -> str:
    m, s = divmod(int(seconds), 60)
    return f"{m:02d}:{s:02d}"


def misspell(word: str, rng: random.Random) -> str:
    """A common slip: one letter of a longer word dropped ("chopping" -> "chpping")."""
    if len(word) < 6:
        return word
    i = rng.randrange(1, len(word) - 1)
    return word[:i] + word[i + 1:]


def _phrasable(a: ActionClass) -> bool:
    return a.phrasable and a.noun not in ("hand", "") and a.verb not in ("let-go",) and ":" not in a.verb


def generate_scoped(b: Behaviour, add, rng: random.Random, fill, per_kind: dict[str, int] | None = None,
                    tag: str = "") -> None:
    """Add the scoped kinds' items for one participant through `add(kind, question, template, split,
    gold, evidence)`; `fill(template, pid, action, noun)` words a template (generate_open._fill)."""
    per = per_kind or PER_SCOPED
    pid = b.participant_id
    key = f"{tag}:{pid}" if tag else pid  # pair ids: one seed's questions pair only with each other
    videos = b.videos
    by_video: dict[str, list] = {v: list(b.steps_by_video[v]) for v in videos}
    counts: dict[ActionClass, Counter] = {}
    for v, ss in by_video.items():
        for s in ss:
            counts.setdefault(s.action, Counter())[v] += 1

    def word(kind: str) -> tuple[str, str, str]:
        pool = SCOPED_TEMPLATES[kind]
        person = rng.choice(sorted(pool))
        i = rng.randrange(len(pool[person]))
        return pool[person][i], f"{kind}/{person}/{i}", person

    def text(t: str, act: ActionClass | None, noun: str = "", typo: bool = False, **kw) -> str:
        q = fill(t.replace("{V}", "{{V}}").replace("{a}", "{{a}}").replace("{z}", "{{z}}").replace("{e}", "{{e}}")
                 .replace("{N}", "{{N}}"), pid, act, noun)
        if typo:
            name = noun_text(noun or (act.noun if act else ""))
            words = name.split()
            longest = max(words, key=len) if words else ""
            if len(longest) >= 6:
                q = q.replace(name, name.replace(longest, misspell(longest, rng)), 1)
        return q.format(**kw)

    # counts in one video, with a counterfactual: the same question on another video whose count differs
    multi = sorted(a for a, c in counts.items() if _phrasable(a) and len(c) >= 2 and sum(c.values()) >= 3)
    for k, a in enumerate(rng.sample(multi, min(per["count_video"], len(multi)))):
        c = counts[a]
        (v1, n1), *rest = c.most_common()
        others = [v for v in videos if v != v1 and c.get(v, 0) != n1]
        t, tid, person = word("count_video")
        pair = f"{key}/count_video/{k}"
        add("count_video", text(t, a, V=v1, typo=k % 3 == 2), tid, person, {"count": n1},
            {"video": v1, "pair": pair, "action": list(a), "cell": CELLS["count_video"]})
        if others:
            v2 = rng.choice(others)
            # every other pair asks the second as an ellipsis: "...in P01_102? And in P01_103?"
            q2 = text(t, a, V=v1, typo=k % 3 == 2) + f" And in {v2}?" if k % 2 else text(t, a, V=v2, typo=k % 3 == 2)
            add("count_video", q2, tid + ("/ellipsis" if k % 2 else ""), person, {"count": c.get(v2, 0)},
                {"video": v2, "pair": pair, "action": list(a), "cell": CELLS["count_video"]})
    # did it happen in V (yes), and in a video where it did not (no): one pair
    for k, a in enumerate(rng.sample(multi, min(per["yes_video"], len(multi)))):
        c = counts[a]
        v1 = rng.choice(sorted(c))
        t, tid, person = word("yes_video")
        pair = f"{key}/yes_video/{k}"
        add("yes_video", text(t, a, V=v1), tid, person, {"yes": True}, {"video": v1, "pair": pair,
                                                                          "cell": CELLS["yes_video"]})
        absent = [v for v in videos if v not in c]
        if absent and k < per["no_video"]:
            v2 = rng.choice(absent)
            q2 = text(t, a, V=v1) + f" What about {v2}?" if k % 2 else text(t, a, V=v2)
            add("no_video", q2, tid + ("/ellipsis" if k % 2 else ""), person, {"yes": False}, {"video": v2, "pair": pair,
                                                                               "cell": CELLS["no_video"]})
    # where last put in V (a pair when another video's last place differs)
    puts: dict[str, dict[str, list]] = {}
    for v, ss in by_video.items():
        for s in ss:
            if s.place and s.action.verb in PUT_VERB_KEYS and s.place != s.action.noun and s.action.noun != "hand":
                puts.setdefault(s.action.noun, {}).setdefault(v, []).append(s)
    nouns = sorted(n for n, d in puts.items() if len(d) >= 1)
    for k, noun in enumerate(rng.sample(nouns, min(per["place_video"], len(nouns)))):
        d = puts[noun]
        vids = sorted(d)
        v1 = rng.choice(vids)
        t, tid, person = word("place_video")
        pair = f"{key}/place_video/{k}"
        add("place_video", text(t, None, noun, typo=k % 3 == 1, V=v1), tid, person, {"place": d[v1][-1].place},
            {"video": v1, "pair": pair, "cell": CELLS["place_video"]})
        diff = [v for v in vids if d[v][-1].place != d[v1][-1].place]
        if diff:
            v2 = rng.choice(diff)
            add("place_video", text(t, None, noun, typo=k % 3 == 1, V=v2), tid, person, {"place": d[v2][-1].place},
                {"video": v2, "pair": pair, "cell": CELLS["place_video"]})
    # first / last thing in V: pairs of two videos whose first (last) actions differ
    ok = [v for v in videos if by_video[v] and _phrasable(by_video[v][0].action) and _phrasable(by_video[v][-1].action)]
    for kind, pick in (("last_in_video", -1), ("first_in_video", 0)):
        chosen = rng.sample(ok, min(per[kind], len(ok)))
        t, tid, person = word(kind)
        for k in range(0, len(chosen), 2):
            pair = f"{key}/{kind}/{k}"
            for v in chosen[k:k + 2]:
                a = by_video[v][pick].action
                add(kind, text(t, None, V=v), tid, person, {"verb": a.verb, "noun": a.noun},
                    {"video": v, "pair": pair, "cell": CELLS[kind]})
    # the first thing in the last / nth session
    for k in range(min(per["first_in_session"], len(videos))):
        t, tid, person = word("first_in_session")
        n = len(videos) if "last" in t else rng.randint(1, min(5, len(videos)))
        v = videos[n - 1]
        if not by_video[v] or not _phrasable(by_video[v][0].action):
            continue
        a = by_video[v][0].action
        add("first_in_session", text(t, None, N=_ORD.get(n, f"{n}th")), tid, person, {"verb": a.verb, "noun": a.noun},
            {"video": v, "cell": CELLS["first_in_session"]})
    # counts in a window of a video (the window and, as its counterfactual, the rest of the video before it)
    dense = [(a, v) for a, c in counts.items() if _phrasable(a) for v, n in c.items() if n >= 3]
    for k, (a, v) in enumerate(rng.sample(sorted(dense), min(per["count_window"], len(dense)))):
        times = sorted(s.start_s for s in by_video[v] if s.action == a)
        lo, hi = int(times[len(times) // 2]) // 60 * 60, int(times[-1]) // 60 * 60 + 60
        inside = sum(1 for x in times if lo <= x <= hi)
        t, tid, person = word("count_window")
        pair = f"{key}/count_window/{k}"
        add("count_window", text(t, a, V=v, a=_clock(lo), z=_clock(hi)), tid, person, {"count": inside},
            {"video": v, "pair": pair, "window": [lo, hi], "cell": CELLS["count_window"]})
        if lo > 0:
            before = sum(1 for x in times if 0 <= x <= lo)
            add("count_window", text(t, a, V=v, a=_clock(0), z=_clock(lo)), tid, person, {"count": before},
                {"video": v, "pair": pair, "window": [0, lo], "cell": CELLS["count_window"]})
    # counts in a video after an event there (the event's first time in the video)
    cands = []
    for (a, v) in sorted(dense):
        ss = by_video[v]
        times = [s.start_s for s in ss if s.action == a]
        for e in ss[:len(ss) // 2]:
            if _phrasable(e.action) and e.action != a and e.action.verb not in ("take", "put", "move") and \
                    counts[e.action].get(v, 0) == 1 and 0 < sum(1 for x in times if x > e.start_s) < len(times):
                cands.append((a, v, e))
                break
    for k, (a, v, e) in enumerate(rng.sample(cands, min(per["count_after"], len(cands)))):
        t, tid, person = word("count_after")
        ev = f"{past(e.action.verb)} the {noun_text(e.action.noun)}"
        n = sum(1 for s in by_video[v] if s.action == a and s.start_s > e.start_s)
        add("count_after", text(t, a, V=v, e=ev), tid, person, {"count": n},
            {"video": v, "event": list(e.action), "cell": CELLS["count_after"]})
    # what usually comes just before an action
    prev: dict[ActionClass, Counter] = {}
    trig_videos: dict[ActionClass, set] = {}
    for v in videos:
        runs = b.runs_by_video[v]
        for r0, r1 in zip(runs, runs[1:]):
            prev.setdefault(r1.action, Counter())[r0.action] += 1
            trig_videos.setdefault(r1.action, set()).add(v)
    befores = []
    for a, c in prev.items():
        if not _phrasable(a):
            continue
        total = sum(c.values())
        (p, n), *rest = c.most_common()
        if total >= 4 and len(trig_videos[a]) >= 2 and n >= 3 and n / total >= 0.3 and p.noun and p != a and \
                (not rest or n >= 1.5 * rest[0][1]):
            befores.append((a, p, n, total))
    for a, p, n, total in rng.sample(sorted(befores), min(per["previous"], len(befores))):
        t, tid, person = word("previous")
        add("previous", text(t, a), tid, person, {"verb": p.verb, "noun": p.noun},
            {"count": n, "of": total, "cell": CELLS["previous"]})
    # the nth time: the video of the second / third occurrence (a pair: the nth and the first, when they differ)
    seq: dict[ActionClass, list[str]] = {}
    for v in videos:
        for s in by_video[v]:
            seq.setdefault(s.action, []).append(v)
    nths = sorted(a for a, vs in seq.items() if _phrasable(a) and len(vs) >= 3 and len(set(vs)) >= 2)
    for k, a in enumerate(rng.sample(nths, min(per["time_nth"], len(nths)))):
        vs = seq[a]
        n = 3 if len(vs) >= 3 and rng.random() < 0.4 else 2
        t, tid, person = word("time_nth")
        add("time_nth", text(t, a, N=_ORD[n]), tid, person, {"video": vs[n - 1]},
            {"nth": n, "cell": CELLS["time_nth"]})
