"""What llama-cpp-python's OpenAI-compatible server (python -m llama_cpp.server, 0.3.36) answers, in
the exact shapes recorded against it, replayed by the scripted server on 127.0.0.1 so that the
default test run keeps the project honest about them. The opt-in group `pytest -m real_model`
(tests/e2e/real_model/) runs the real server."""

from __future__ import annotations

import json

import pytest
from pydantic import BaseModel
from support.scripted_server import ScriptedServer, Turn

from memora_graph.agent.loop import ModelPolicy, run_agent
from memora_graph.llm import ModelServerError, extract_json, get_backend

MESSAGES = [{"role": "user", "content": "Where is the plate kept?"}]


class Where(BaseModel):
    object: str
    place: str
    count: int


def _backend(server, **options):
    return get_backend("openai", base_url=server.base_url, model="smollm2-135m", timeout_s=5, **options)


# Its reply to {"response_format": {"type": "json_schema", ...}} (pydantic's validation error of the request).
JSON_SCHEMA_REFUSED = (
    "1 validation error:\n  {'type': 'literal_error', 'loc': ('body', 'response_format', 'type'), "
    "'msg': \"Input should be 'text' or 'json_object'\", 'input': 'json_schema', "
    "'ctx': {'expected': \"'text' or 'json_object'\"}}\n\n  File \"llama_cpp/server/app.py\", line 376, "
    "in create_chat_completion\n    POST /v1/chat/completions")


def test_json_schema_refused_with_http_500_names_the_option_that_works():
    with ScriptedServer([Turn(status=500, error=JSON_SCHEMA_REFUSED)]) as server:
        backend = _backend(server, max_retries=0)
        with pytest.raises(ModelServerError) as info:
            backend.chat(MESSAGES, role="consolidation", response_model=Where)
    message = str(info.value)
    assert "HTTP 500" in message and "Input should be 'text' or 'json_object'" in message
    assert "structured_output=json_object" in message and "json_schema=false" in message
    assert backend.call_log.records[0].ok is False


def test_structured_output_json_object_sends_the_schema_in_the_form_llama_cpp_takes():
    # A reply its schema grammar let through: a raw newline inside a string (not strict JSON).
    reply = '{ "object": "plate",\n "place": "cupboard\nshelf", "count": 2}'
    with ScriptedServer([reply]) as server:
        parsed = _backend(server, structured_output="json_object").chat(
            MESSAGES, role="consolidation", response_model=Where).parsed
        sent = server.requests[0]["response_format"]
    assert sent == {"type": "json_object", "schema": Where.model_json_schema()}
    assert parsed == Where(object="plate", place="cupboard\nshelf", count=2)


def test_default_structured_output_is_openais_json_schema():
    with ScriptedServer(['{"object": "plate", "place": "sink", "count": 1}']) as server:
        _backend(server).chat(MESSAGES, role="consolidation", response_model=Where)
        sent = server.requests[0]["response_format"]
    assert sent["type"] == "json_schema" and sent["json_schema"]["schema"] == Where.model_json_schema()


def test_control_characters_inside_strings_are_accepted_where_the_json_is_embedded():
    assert extract_json('Here:\n```json\n{"a": "x\ty"}\n```') == {"a": "x\ty"}
    assert extract_json('noise {"a": "line one\nline two"} more') == {"a": "line one\nline two"}


# Its native tool call (chatml-function-calling, tool_choice "auto"): content null, an id built
# from the completion id, a legacy `function_call` beside `tool_calls`, arguments with spaces.
TOOL_CALL_REPLY = {
    "id": "chatcmpl-a80e6be2", "object": "chat.completion", "created": 1795483891, "model": "smollm2-135m",
    "choices": [{"index": 0, "logprobs": None, "finish_reason": "tool_calls", "message": {
        "content": None, "role": "assistant",
        "tool_calls": [{"id": "call__0_search_cmpl-3ec97897", "type": "function",
                        "function": {"name": "search", "arguments": "{ \"query\": \"plate\" } "}}],
        "function_call": {"name": "search:", "arguments": "{ \"query\": \"plate\" } "}}}],
    "usage": {"prompt_tokens": 247, "completion_tokens": 8, "total_tokens": 255},
}


class _Memory:
    participant = "P01"

    def __init__(self):
        self.queries = []

    def schemas(self):
        return [{"type": "function", "function": {
            "name": "search", "description": "Search the memory.",
            "parameters": {"type": "object", "properties": {"query": {"type": "string"}}, "required": ["query"]}}}]

    def call(self, name, arguments):
        self.queries.append(arguments["query"])
        return [{"text": f"put {arguments['query']} in cupboard"}]


def test_agent_asks_for_tool_choice_auto_and_runs_llama_cpp_native_tool_calls():
    memory = _Memory()
    view = {"participant_id": "P01", "question_id": "q1", "question": "Where is the plate kept?",
            "choices": ["sink", "cupboard", "fridge", "rack", "not available"]}
    with ScriptedServer([Turn(raw_body=json.dumps(TOOL_CALL_REPLY)), "Answer: B"]) as server:
        result = run_agent(ModelPolicy(_backend(server)), memory, "eam_qa", view, "flat1d")
        first, second = server.requests
    # Without "auto" said out loud, chatml-function-calling leaves the tools out of the prompt.
    assert first["tool_choice"] == "auto" and first["tools"][0]["function"]["name"] == "search"
    assert memory.queries == ["plate"]
    assert [c["format"] for c in result.tool_calls] == ["native"]
    # The assistant turn goes back with string content: the server answers content null with HTTP 500.
    assistant = second["messages"][-2]
    assert assistant["role"] == "assistant" and assistant["content"] == ""
    assert assistant["tool_calls"][0]["id"] == "call__0_search_cmpl-3ec97897"
    assert second["messages"][-1]["role"] == "tool"
    assert result.final_text == "Answer: B"
