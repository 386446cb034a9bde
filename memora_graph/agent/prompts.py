"""The prompt families of the seven conditions (paper: "Planning prompt families" figure and the
EAM-QA prompts), as versioned functions. Every family shares the same final-answer constraint and
the same forced-answer prompt; they differ in what memory and which tools they describe.
"""

from __future__ import annotations

from typing import Any

PROMPT_VERSION = "2026-05-a"
FAMILIES = ("parametric", "flat1d", "graph2d", "memora_episodic", "memora")
OPTION_LINE = "{letter}) {text}"

# -- EAM-QA ---------------------------------------------------------------------------------------

_QA_MEMORY = {
    "parametric": "You answer questions about a person's kitchen activities. You have no access to their memory.",
    "flat1d": ("You answer questions about a person's kitchen activities using their memory: a chronological "
               "list of time-stamped text observations. Use the `search(query)` tool to retrieve relevant "
               "observations before answering."),
    "graph2d": ("You answer questions about a person's kitchen activities using their memory: an entity-relation "
                "graph of activities, objects, places and patterns. Use `search` for related nodes, "
                "`get_object_history` for one object's history and `get_state_at_time` for a moment."),
    "memora_episodic": ("You answer questions about a person's kitchen activities using their typed episodic "
                        "memory (environment, entity and activity stores). Use `search` and the entity, "
                        "activity and temporal tools to recover the relevant episodes."),
    "memora": ("You answer questions about a person's kitchen activities using their typed memory: episodic "
               "stores plus consolidated routines and preferences. Use `search`, and the routine, preference, "
               "entity and activity tools when the question is about habits, preferences or routines."),
}

QA_RULES = (
    "Answer with exactly one option letter. Option E means the information is not available: choose E "
    "when the evidence does not support any of A-D. End your reply with 'Answer: X'."
)


def qa_system(family: str) -> str:
    return f"{_QA_MEMORY[family]}\n\n{QA_RULES}"


def format_question(view: dict[str, Any]) -> str:
    letters = "ABCDE"
    options = "\n".join(OPTION_LINE.format(letter=letters[i], text=c) for i, c in enumerate(view["choices"][:5]))
    return f"Participant: {view['participant_id']}\n\nQuestion: {view['question']}\n\nOptions:\n{options}"


def qa_forced(calls_made: list[str]) -> str:
    made = "; ".join(calls_made) if calls_made else "none"
    return ("Tool use is now disabled. Using only the evidence above, choose one option A-E "
            f"(E if the evidence is insufficient). Tool calls made so far: {made}. "
            "Reply with 'Answer: X' and nothing else.")


# -- Planning ---------------------------------------------------------------------------------------

_PLAN_MEMORY = {
    "parametric": ("You are a robot planning assistant. You receive a task and a participant id. Do not assume "
                   "any participant-specific memory."),
    "flat1d": ("You are a robot planning assistant with access to the person's text memory through "
               "`search(query)`. Retrieve relevant observations before planning and ground the final plan in "
               "retrieved evidence when available."),
    "graph2d": ("You are a robot planning assistant with access to the person's entity-relation graph through "
                "graph-oriented entity, activity and temporal retrieval (`search`, `get_object_history`, "
                "`get_state_at_time`). Retrieve procedural evidence, then ground named entities and locations."),
    "memora_episodic": ("You are a robot planning assistant with the person's typed episodic memory. Use the "
                        "entity, activity, temporal and unified search tools: recover relevant episodes, then "
                        "ground entities and locations."),
    "memora": ("You are a robot planning assistant for a specific person's kitchen. Call `get_routine_skill` "
               "first; call `get_preferences` when preferences may affect the plan; use the object tools to "
               "ground objects and places; use generic search only as a fallback."),
}

PLAN_RULES = (
    "The final answer is an ordered, executable plan: 'Plan:' followed by numbered steps, each with an "
    "action, an object and a location (e.g. '1. Pick up the red mug from the drying rack')."
)


def plan_system(family: str) -> str:
    return f"{_PLAN_MEMORY[family]}\n\n{PLAN_RULES}"


def format_task(task: dict[str, Any]) -> str:
    return f"Participant: {task['participant_id']}\nTask: {task['task_query']}"


def plan_forced(calls_made: list[str]) -> str:
    made = "; ".join(calls_made) if calls_made else "none"
    return ("Tool use is disabled. Do not emit tool-call XML or analysis tags. Return only a parseable final "
            f"plan in the form 'Plan: 1. ... 2. ...'. Tool calls made so far: {made}.")


PREMATURE_RETRY = {
    "eam_qa": "Your reply has no answer. Reply with 'Answer: X' where X is one of A-E.",
    "planning": "Your reply has no plan. Reply with 'Plan:' followed by numbered steps.",
}


def system_prompt(task_kind: str, family: str) -> str:
    if family not in FAMILIES:
        raise ValueError(f"unknown prompt family {family!r}; known: {', '.join(FAMILIES)}")
    return qa_system(family) if task_kind == "eam_qa" else plan_system(family)


def forced_prompt(task_kind: str, calls_made: list[str]) -> str:
    return qa_forced(calls_made) if task_kind == "eam_qa" else plan_forced(calls_made)
