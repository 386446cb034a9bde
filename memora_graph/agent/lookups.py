"""Intent -> the typed lookups a careful reader makes, with whatever tools a condition advertises.

Each need is asked of the most specific tool the condition has, and of `search` where that is
all it has: the episodes around the subject (search_activities, else search), the person's
consolidated habits and preferences about it (get_preferences), routines for it
(get_routine_skill), the named video's activity log (get_video_activities), and whether memory
holds the subject at all (search_objects, else get_object_history). Lookups go in rounds of at
most three calls (the agent loop's cap per response); the most important need comes first.
"""

from __future__ import annotations

import re
from typing import Any

from memora_graph.agent.reading import Intent

MAX_TOP_K = 30
_LEAD = re.compile(r"^(?:when|after|while|once|during|in|as|before)\s+", re.I)
_PID = re.compile(r"\bP\d{2}\b(?:'s)?\s*")
_WH = re.compile(r"[,.]?\s*\b(what|which|how|where|who|why)\b.*$", re.I)


def focus(intent: Intent) -> str:
    """The words of the situation the question is about, without the question ("When P01 has just
    stirred the potatoes, what ..." -> "has just stirred the potatoes")."""
    text = _WH.sub("", intent.text) if not re.match(r"^\s*(what|which|how|where)\b", intent.text, re.I) else intent.text
    text = _PID.sub("", text)
    text = _LEAD.sub("", text.strip())
    text = re.sub(r"\s+", " ", text).strip(" ,.?")
    return text or _PID.sub("", intent.text).strip(" ?")


def subject_words(intent: Intent) -> str:
    """The subject's object words, for an object lookup ("the bowl", "potato")."""
    return " ".join(n.split(":")[0].replace("_", " ") for n in intent.subject_nouns[:2])


def plan(intent: Intent, tools: list[str]) -> list[list[tuple[str, dict[str, Any]]]]:
    """Rounds of (tool, arguments) for a question, using only the advertised `tools`."""
    has = set(tools).__contains__
    query = focus(intent)
    subject = subject_words(intent)
    first: list[tuple[str, dict[str, Any]]] = []
    second: list[tuple[str, dict[str, Any]]] = []

    def episodes(q: str) -> tuple[str, dict[str, Any]] | None:
        if has("search_activities"):
            return "search_activities", {"query": q, "top_k": MAX_TOP_K}
        if has("search") and "get_object_history" not in tools:  # Flat-1D: one text search
            return "search", {"query": q, "top_k": MAX_TOP_K}
        if has("search"):
            return "search", {"query": q}
        return None

    if intent.kind == "recall" and has("get_video_activities"):
        for v in intent.videos[:2]:
            first.append(("get_video_activities", {"video": v, "query": subject or ""}))
        if subject:
            second.append(("get_video_activities", {"video": intent.videos[0], "query": ""}))
    if intent.kind == "routine" and has("get_routine_skill"):
        first.append(("get_routine_skill", {"goal_query": query, "top_k": 5}))
    if intent.kind in ("habit", "preference", "routine") and has("get_preferences"):
        first.append(("get_preferences", {"query": query, "top_k": 10}))
    call = episodes(query if intent.kind != "recall" else f"{' '.join(intent.videos)} {query}")
    if call:
        first.append(call)
    if subject and subject != query:
        call = episodes(subject if intent.kind != "recall" else f"{' '.join(intent.videos)} {subject}")
        if call and call not in first:
            second.append(call)
    if subject and subject != query and intent.kind in ("habit", "preference", "routine") and has("get_preferences"):
        # the person's consolidated habits and storage about the object itself: the situation's
        # wording ("briefly sets the garlic down during preparation") finds records about others
        second.append(("get_preferences", {"query": subject, "top_k": 10}))
    if subject:
        if has("search_objects"):
            second.append(("search_objects", {"query": subject, "top_k": 5}))
        elif has("get_object_history"):
            second.append(("get_object_history", {"object_query": subject}))
    rounds = [first[:3], first[3:] + second]
    out = []
    for r in rounds:
        while r:
            out.append(r[:3])
            r = r[3:]
    return [r for r in out if r]
