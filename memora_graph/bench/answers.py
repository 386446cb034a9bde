"""Reading a reply: the answer letter of an EAM-QA reply and the steps of a plan,
whatever shape the model wrote them in."""

from __future__ import annotations

import re

CONTENT_LETTERS = frozenset("ABCD")
_ANSWER_MARKER = re.compile(
    r"(?i:final\s+answer|answer|correct\s+option|option|choice)\s*(?:is\b)?\s*[:=\-]?\s*[*_`\"'(\[]*\s*([A-Ea-e])(?![A-Za-z0-9])"
)
_ONLY_LETTER = re.compile(r"^\W*([A-E])\W*$")
_LINE_LETTER = re.compile(r"^\s*[*_`]*\(?([A-E])[).:\]]\s", re.M)
_BOLD_LETTER = re.compile(r"\*\*\(?([A-E])\)?\*\*")
_PAREN_LETTER = re.compile(r"\b([A-E])\)")
_STANDALONE = re.compile(r"\b([A-E])\b")


def parse_answer_letter(text: str | None, choices: list[str] | None = None) -> str:
    """The chosen letter A-E, or "" when none can be read.

    In order: the last explicit marker ("Answer: C", "final answer is **D**", "Option E" -- a
    final "Answer: C" with nothing after it counts); a reply that is only a letter; a single
    distinct letter opening a line ("B) ...", "(B) ...", "B. ..."); a single bold letter; a single
    distinct "X)"; the first standalone capital letter that is not the article "A" (an "A"
    followed by a lowercase word is read as the article); finally the one option whose text
    appears in the reply.
    """
    if not text:
        return ""
    text = re.sub(r"<think>.*?</think>", " ", text, flags=re.S).strip()
    markers = _ANSWER_MARKER.findall(text)
    if markers:
        return markers[-1].upper()
    m = _ONLY_LETTER.match(text)
    if m:
        return m.group(1)
    for pattern in (_LINE_LETTER, _BOLD_LETTER, _PAREN_LETTER):
        found = set(pattern.findall(text))
        if len(found) == 1:
            return found.pop()
    for m in _STANDALONE.finditer(text):
        letter = m.group(1)
        if letter == "A" and re.match(r"\s+[a-z]", text[m.end():]):
            continue
        return letter
    if choices:
        low = text.lower()
        hits = [i for i, c in enumerate(choices[:5])
                if len(c.strip(" .")) > 1 and re.search(r"\b" + re.escape(c.lower().strip(" .")) + r"\b", low)]
        if len(hits) == 1:
            return "ABCDE"[hits[0]]
    return ""


_CONFIDENCE = re.compile(r"^Confidence:\s*([01](?:\.\d+)?)\s*$", re.M)
_FEATURES = re.compile(r"^Features:\s*(\{.*\})\s*$", re.M)


def parse_confidence(text: str | None) -> float | None:
    """The probability a reply gives its answer ("Confidence: 0.734" on a line of its own), or None."""
    m = _CONFIDENCE.findall(text or "")
    return float(m[-1]) if m else None


def parse_reader_features(text: str | None) -> dict | None:
    """The evidence features the offline reader reports ("Features: {json}"), or None."""
    import json

    m = _FEATURES.findall(text or "")
    if not m:
        return None
    try:
        data = json.loads(m[-1])
    except json.JSONDecodeError:
        return None
    return data if isinstance(data, dict) else None


MAX_PLAN_STEPS = 15
_STRIP = [
    re.compile(r"<tool_call>.*?</tool_call>", re.S | re.I),
    re.compile(r"<tool_response>.*?</tool_response>", re.S | re.I),
    re.compile(r"\{\"query\":.*?\}\}", re.S),
]
_NUMBERED = re.compile(r"^\s*\d+[.)]\s*(.+?)\s*$")
_NUMBERED_STRICT = re.compile(r"^\s*\d+[.)]\s+(.+?)\s*$")
_BULLET = re.compile(r"^\s*[-*]\s+(.+?)\s*$")


def _dedup_cap(steps: list[str]) -> list[str]:
    out: list[str] = []
    for s in steps:
        if not out or out[-1].lower() != s.lower():
            out.append(s)
    return out[:MAX_PLAN_STEPS]


def extract_plan(text: str | None) -> list[str]:
    """Plan steps from a model reply: a numbered block after "Plan:" (the last
    such block wins), else >= 2 numbered lines, else >= 2 bullets; consecutive duplicates
    dropped; at most 15 steps."""
    if not text:
        return []
    for pattern in _STRIP:
        text = pattern.sub(" ", text)
    lines = text.splitlines()
    heads = [i for i, line in enumerate(lines) if re.search(r"plan\s*:", line, re.I)]
    for h in reversed(heads):
        items: list[str] = []
        for line in lines[h + 1:]:
            m = _NUMBERED.match(line)
            if m:
                items.append(m.group(1))
            elif line.strip() and items:
                break
            elif line.strip() and not items:
                break
        if items:
            return _dedup_cap(items)
    numbered = [m.group(1) for line in lines if (m := _NUMBERED_STRICT.match(line))]
    if len(numbered) >= 2:
        return _dedup_cap(numbered)
    bullets = [m.group(1) for line in lines if (m := _BULLET.match(line))]
    if len(bullets) >= 2:
        return _dedup_cap(bullets)
    return []


def plan_from_result(result: dict) -> list[str]:
    """The scored plan of a result record: generated_plan, else plan_steps; a string is split into lines."""
    plan = result.get("generated_plan")
    if plan is None or plan == [] or plan == "":
        plan = result.get("plan_steps")
    if plan is None:
        return []
    if isinstance(plan, str):
        return [line.strip() for line in plan.splitlines() if line.strip()]
    return [str(s).strip() for s in plan if str(s).strip()]
