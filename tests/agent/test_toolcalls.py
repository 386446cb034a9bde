"""The tool-call parser: every format it reads, the cap, de-duplication, rescue."""

from __future__ import annotations

import json

import pytest

from memora_graph.agent import ToolCall, parse_tool_calls, strip_tool_markup
from memora_graph.llm import get_backend
from support.scripted_server import ScriptedServer, Turn, tool_call

TOOLS = ["search", "get_state_at_time", "get_object_history", "search_objects", "search_activities",
         "search_patterns"]


def calls(content, native=None, available=TOOLS, **kwargs):
    return [(c.name, c.arguments) for c in parse_tool_calls(content, native, available=available, **kwargs)]


# -- native OpenAI function calls ---------------------------------------------------------------


def test_native_tool_calls_keep_their_ids_and_decode_arguments():
    native = [tool_call("search", {"query": "red mug"}, id="call_a"),
              tool_call("get_state_at_time", '{"time_seconds": 120}', id="call_b")]
    parsed = parse_tool_calls("", native, available=TOOLS)
    assert parsed == [ToolCall(name="search", arguments={"query": "red mug"}, id="call_a"),
                      ToolCall(name="get_state_at_time", arguments={"time_seconds": 120}, id="call_b")]


def test_native_calls_win_over_text_and_broken_native_arguments_are_rescued():
    native = [{"id": "c1", "type": "function", "function": {"name": "search", "arguments": '{"query": "kettle",'}}]
    text = '<tool_call>{"name": "search", "arguments": {"query": "from text"}}</tool_call>'
    assert calls(text, native) == [("search", {"query": "kettle"})]


def test_native_calls_to_tools_not_offered_are_ignored():
    native = [tool_call("delete_memory", {"all": True}), tool_call("search", {"query": "pan"})]
    assert calls(None, native) == [("search", {"query": "pan"})]


def test_reply_from_a_real_server_round_trip():
    script = [Turn(content=None, tool_calls=[tool_call("search_objects", {"query": "knife"})]),
              Turn(content='Let me check.\n<tool_call>\n{"name": "get_object_history", '
                           '"arguments": {"object_query": "knife"}}\n</tool_call>')]
    with ScriptedServer(script) as server:
        backend = get_backend("openai", base_url=server.base_url, model="m")
        first = backend.chat([{"role": "user", "content": "Where is the knife?"}], role="answer")
        second = backend.chat([{"role": "user", "content": "Where is the knife?"}], role="answer")
    assert calls(first.content, first.tool_calls) == [("search_objects", {"query": "knife"})]
    assert calls(second.content, second.tool_calls) == [("get_object_history", {"object_query": "knife"})]
    assert strip_tool_markup(second.content) == "Let me check."


# -- format 1: <tool_call> JSON ------------------------------------------------------------------


@pytest.mark.parametrize("text, expected", [
    ('<tool_call>\n{"name": "search", "arguments": {"query": "red mug"}}\n</tool_call>',
     [("search", {"query": "red mug"})]),
    # arguments as a JSON string
    ('<tool_call>{"name": "get_state_at_time", "arguments": "{\\"time_seconds\\": 95.5}"}</tool_call>',
     [("get_state_at_time", {"time_seconds": 95.5})]),
    # "parameters" instead of "arguments", and two calls
    ('<tool_call>{"name": "search", "parameters": {"query": "pan"}}</tool_call>\n'
     '<tool_call>{"name": "search_objects", "arguments": {"query": "lid"}}</tool_call>',
     [("search", {"query": "pan"}), ("search_objects", {"query": "lid"})]),
    # the closing tag cut off at the end of the reply
    ('<tool_call>{"name": "search", "arguments": {"query": "sponge"}}',
     [("search", {"query": "sponge"})]),
])
def test_tool_call_tags(text, expected):
    assert calls(text) == expected


@pytest.mark.parametrize("text, expected", [
    # trailing comma
    ('<tool_call>{"name": "search", "arguments": {"query": "red mug", }}</tool_call>', {"query": "red mug"}),
    # missing closing braces
    ('<tool_call>{"name": "search", "arguments": {"query": "red mug"</tool_call>', {"query": "red mug"}),
    # unterminated string
    ('<tool_call>{"name": "search", "arguments": {"query": "red mug</tool_call>', {"query": "red mug"}),
    # Python-style quotes
    ("<tool_call>{'name': 'search', 'arguments': {'query': 'red mug'}}</tool_call>", {"query": "red mug"}),
    # corrupted Hermes: <function=NAME", "arguments": {...}
    ('<tool_call>\n<function=search", "arguments": {"query": "red mug"}}\n</tool_call>', {"query": "red mug"}),
])
def test_broken_json_is_rescued(text, expected):
    assert calls(text) == [("search", expected)]


def test_rescue_keeps_numbers_and_several_arguments():
    text = '<tool_call>{"name": "search", "arguments": {"query": "pan", "top_k_per_category": 2,, }</tool_call>'
    assert calls(text) == [("search", {"query": "pan", "top_k_per_category": 2})]


# -- format 2: fenced blocks and bare JSON --------------------------------------------------------


@pytest.mark.parametrize("text", [
    'I will look it up.\n```tool_call\n{"name": "search", "arguments": {"query": "mug"}}\n```',
    '```json\n{"name": "search", "arguments": {"query": "mug"}}\n```',
    '```\n{"name": "search", "arguments": {"query": "mug"}}\n```',
    'Calling {"name": "search", "arguments": {"query": "mug"}} now.',
])
def test_fenced_and_bare_json_calls(text):
    assert calls(text) == [("search", {"query": "mug"})]


def test_json_that_is_not_a_call_is_not_a_call():
    assert calls('```json\n{"answer": "C"}\n```') == []


# -- format 3: Hermes XML ---------------------------------------------------------------------------


def test_hermes_xml_parameters():
    text = ("<tool_call>\n<function=get_object_history>\n<parameter=object_query>\nchopping board\n</parameter>\n"
            "</function>\n</tool_call>\n<function=get_state_at_time><parameter=time_seconds>340</parameter></function>")
    assert calls(text) == [("get_object_history", {"object_query": "chopping board"}),
                           ("get_state_at_time", {"time_seconds": 340})]


# -- format 4: Gemma --------------------------------------------------------------------------------


@pytest.mark.parametrize("text, expected", [
    ("call:search{query:<escape>red mug, the big one<escape>}", ("search", {"query": "red mug, the big one"})),
    ('<|tool_call>call:search{query:<|"|>pan<|"|>,top_k_per_category:2}<tool_call|>',
     ("search", {"query": "pan", "top_k_per_category": 2})),
    ("```tool_code\ncall:get_state_at_time{time_seconds:120}\n```", ("get_state_at_time", {"time_seconds": 120})),
    ('call:search_objects{query:"it\'s blue"}', ("search_objects", {"query": "it's blue"})),
])
def test_gemma_calls(text, expected):
    assert calls(text) == [expected]


# -- format 5: plain text -------------------------------------------------------------------------


def test_plain_text_calls():
    text = ('First search("pan (large)"), then get_state_at_time(120), get_object_history("knife").\n'
            "Also search_objects(query='lid').")
    assert calls(text, max_calls=5) == [
        ("search", {"query": "pan (large)"}), ("get_state_at_time", {"time_seconds": 120}),
        ("get_object_history", {"object_query": "knife"}), ("search_objects", {"query": "lid"}),
    ]


def test_plain_text_activities_patterns_and_bare_words():
    assert calls('search_activities("wash up") search_patterns("coffee habit")') == [
        ("search_activities", {"query": "wash up"}), ("search_patterns", {"query": "coffee habit"})]
    assert calls("search(user's mug)") == [("search", {"query": "user's mug"})]


def test_plain_text_only_for_offered_tools():
    text = 'search_patterns("coffee") and search("coffee") and re.search("x") and lookup("y")'
    assert calls(text, available=["search"]) == [("search", {"query": "coffee"})]
    assert calls(text, available=["get_state_at_time"]) == []


def test_positional_argument_follows_the_offered_schema():
    schema = [{"type": "function", "function": {"name": "get_routine_skill", "parameters": {
        "type": "object", "properties": {"top_k": {"type": "integer"}, "goal": {"type": "string"}},
        "required": ["goal"]}}}]
    assert calls('get_routine_skill("make tea")', available=schema) == [("get_routine_skill", {"goal": "make tea"})]


# -- priority, de-duplication, cap, unknown names ------------------------------------------------


def test_the_first_format_that_yields_a_call_wins():
    text = ('<tool_call>{"name": "search", "arguments": {"query": "a"}}</tool_call>\n'
            'and maybe search("b") later')
    assert calls(text) == [("search", {"query": "a"})]


def test_calls_inside_tool_responses_and_thinking_are_not_calls():
    text = ('<think>I could call search("x")</think><tool_response>{"name": "search", "arguments": '
            '{"query": "old"}}</tool_response>The answer is C.')
    assert calls(text) == []


def test_duplicates_are_dropped_on_name_and_canonical_arguments():
    text = ('<tool_call>{"name": "search", "arguments": {"query": "pan", "category": "objects"}}</tool_call>'
            '<tool_call>{"name": "search", "arguments": {"category": "objects", "query": "pan"}}</tool_call>'
            '<tool_call>{"name": "search", "arguments": {"query": "lid"}}</tool_call>')
    parsed = parse_tool_calls(text, available=TOOLS)
    assert [c.arguments["query"] for c in parsed] == ["pan", "lid"]
    assert len({c.id for c in parsed}) == 2


def test_at_most_three_calls_per_response_by_default():
    text = "".join(f'<tool_call>{{"name": "search", "arguments": {{"query": "q{i}"}}}}</tool_call>' for i in range(5))
    assert [a["query"] for _, a in calls(text)] == ["q0", "q1", "q2"]
    assert len(calls(text, max_calls=4)) == 4
    assert len(calls(text, max_calls=1)) == 1


def test_unknown_tool_names_are_ignored_in_every_format():
    text = ('<tool_call>{"name": "rm_rf", "arguments": {}}</tool_call>'
            '<tool_call>{"name": "search", "arguments": {"query": "ok"}}</tool_call>')
    assert calls(text) == [("search", {"query": "ok"})]
    assert calls("<function=rm_rf><parameter=x>1</parameter></function>") == []
    assert calls("call:rm_rf{x:1}") == []


def test_names_match_case_insensitively_and_are_normalized():
    assert calls('<tool_call>{"name": "Search", "arguments": {"query": "ok"}}</tool_call>') == [("search", {"query": "ok"})]


def test_tool_call_round_trips_to_the_openai_shape():
    call = parse_tool_calls('search("mug")', available=TOOLS)[0]
    shape = call.to_openai()
    assert shape["type"] == "function" and shape["id"] == call.id
    assert json.loads(shape["function"]["arguments"]) == {"query": "mug"}
    assert parse_tool_calls(None, [shape], available=TOOLS) == [call]
    assert call.key == ("search", '{"query":"mug"}')


def test_no_calls_in_a_final_answer():
    assert calls("Plan:\n1. Take the kettle.\n2. Fill it with water.") == []
    assert calls("") == [] and calls(None) == []


# -- strip_tool_markup ------------------------------------------------------------------------


def test_strip_tool_markup_leaves_only_the_prose():
    text = ('<think>reasoning</think>Let me check.\n<tool_call>{"name": "search", "arguments": {"query": "x"}}'
            '</tool_call>\n<tool_response>{"objects": []}</tool_response>\n'
            '```tool_call\n{"name": "search", "arguments": {"query": "y"}}\n```\n'
            "<function=search><parameter=query>z</parameter></function>\n"
            "<|tool_call>call:search{query:<escape>w<escape>}<tool_call|>\n\n\n"
            "Answer: C")
    assert strip_tool_markup(text) == "Let me check.\n\nAnswer: C"


def test_strip_tool_markup_keeps_ordinary_json_and_plans():
    text = 'Plan:\n1. Open the fridge.\n2. Take the milk.\n```json\n{"steps": 2}\n```'
    assert strip_tool_markup(text) == text
    assert strip_tool_markup('{"name": "search", "arguments": {"query": "q"}} Answer: B') == "Answer: B"
    assert strip_tool_markup(None) == ""
