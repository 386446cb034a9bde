"""Scripted model words for the scripted server's `responder=` mode: each reply is a pure function
of the request, so any number of requests can be in flight in any order and a run's records do not
depend on which arrived first. Used by `memora perf model` and the concurrency tests.

`agent`: the answer agent. With tools and no tool result yet, it calls `search` (or the first
tool) with the question; then it answers: 'Answer: X' (X from a hash of the question) for EAM-QA,
a three-step plan for planning tasks. A question whose text contains FAIL-ITEM gets a reply that is
not a chat completion (so that item fails and is recorded as failed)."""

from __future__ import annotations

import hashlib
import json
import re
from typing import Any

from memora_graph.testing.scripted_server import Turn, tool_call

USAGE = {"prompt_tokens": 1200, "completion_tokens": 40}


def _first_user(messages: list[dict[str, Any]]) -> str:
    for m in messages:
        if m.get("role") == "user":
            content = m.get("content")
            return content if isinstance(content, str) else json.dumps(content)
    return ""


def _has_tool_results(messages: list[dict[str, Any]]) -> bool:
    return any(m.get("role") == "tool" or (m.get("role") == "user" and "<tool_response>" in str(m.get("content")))
               for m in messages)


def agent(body: dict[str, Any]) -> Turn:
    messages = body["messages"]
    user = _first_user(messages)
    if "FAIL-ITEM" in user:
        return Turn(raw_body="<html>bad gateway</html>")
    digest = int(hashlib.sha256(user.encode()).hexdigest()[:8], 16)
    question = re.search(r"(?:Question|Task): (.*)", user)
    query = (question.group(1) if question else user)[:80].strip() or "kitchen"
    tools = body.get("tools") or []
    if tools and not _has_tool_results(messages):
        names = [t["function"]["name"] for t in tools]
        name = "search" if "search" in names else names[0]
        return Turn(tool_calls=[tool_call(name, {"query": query})], usage=USAGE)
    if "Options:" in user:
        return Turn(content=f"The records point to one option.\nAnswer: {'ABCDE'[digest % 5]}", usage=USAGE)
    return Turn(content="Plan:\n1. Pick up the plate from the counter.\n2. Wash the plate at the sink.\n"
                        "3. Put the plate on the drying rack.", usage=USAGE)


def _minimal(schema: dict[str, Any], defs: dict[str, Any]) -> Any:
    """The smallest value a JSON schema accepts for its required fields (empty lists, "" , 0)."""
    if "$ref" in schema:
        return _minimal(defs[schema["$ref"].split("/")[-1]], defs)
    kind = schema.get("type")
    if kind == "object" or "properties" in schema:
        props = schema.get("properties", {})
        return {k: _minimal(props[k], defs) for k in schema.get("required", []) if k in props}
    return {"array": [], "string": "", "integer": 0, "number": 0, "boolean": False}.get(kind)


def video(body: dict[str, Any]) -> Turn:
    """The video build's models: perception (a plausible layered record, objects moving between
    places), the entity editor (ADD for every observation group), and the smallest valid reply
    for any other structured step (consolidation, enrichment)."""
    from memora_graph.testing.synthetic import scripted_perception

    fmt = (body.get("response_format") or {})
    schema = (fmt.get("json_schema") or {}).get("schema") or fmt.get("schema") or {}
    name = (fmt.get("json_schema") or {}).get("name", "")
    text = json.dumps(body["messages"][-1].get("content"))
    turn = int(hashlib.sha256(text.encode()).hexdigest()[:8], 16) % 8
    if name == "PerceptionReply":
        return Turn(content=json.dumps(scripted_perception(turn, 8)),
                    usage={"prompt_tokens": 3000, "completion_tokens": 600})
    if name == "EditorReply":
        ops = [{"event": "ADD", "observation": g, "object_id": "new", "data": {"name": "x"}, "reason": "seen"}
               for g in range(9)]
        return Turn(content=json.dumps({"object_operations": ops}), usage={"prompt_tokens": 900, "completion_tokens": 200})
    return Turn(content=json.dumps(_minimal(schema, schema.get("$defs", {}))), usage=USAGE)
