"""The model-backend registry and the `openai` backend against a real HTTP server on 127.0.0.1."""

from __future__ import annotations

import hashlib
import json
import socket
import subprocess
import sys
import time
import types

import pytest
from pydantic import BaseModel, Field

from memora_graph.errors import MemoraError
from memora_graph.llm import (
    BackendOptionsError,
    CallLog,
    ModelReplyError,
    ModelServerDownError,
    ModelServerError,
    ModelUnavailableError,
    UnknownBackendError,
    audio_part,
    extract_json,
    get_backend,
    image_part,
    list_backends,
    prompt_hash,
    register_backend,
    summarize_calls,
    text_part,
    unregister_backend,
)
from memora_graph.llm.backends import Backend, OfflineOptions
from support.scripted_server import ScriptedServer, Turn, tool_call

MESSAGES = [{"role": "system", "content": "You answer briefly."}, {"role": "user", "content": "Where is the mug?"}]


class Answer(BaseModel):
    answer: str = Field(pattern="^[A-E]$")
    evidence: list[str] = []


def openai_backend(server: ScriptedServer, **options):
    options = {"model": "test-model", "timeout_s": 5, **options}
    return get_backend("openai", base_url=server.base_url, **options)


# -- plain chat and the protocol ----------------------------------------------------------------


def test_plain_chat_sends_a_chat_completion_request():
    with ScriptedServer([Turn(content="On the drying rack.", usage={"prompt_tokens": 21, "completion_tokens": 6})]) as server:
        backend = openai_backend(server, temperature=0.0, max_tokens=64)
        reply = backend.chat(MESSAGES, role="answer")
    assert reply.content == "On the drying rack."
    assert reply.tool_calls == [] and reply.parsed is None
    assert reply.usage == {"prompt_tokens": 21, "completion_tokens": 6, "total_tokens": 27}
    body = server.requests[0]
    assert body["model"] == "test-model"
    assert body["messages"] == MESSAGES
    assert body["temperature"] == 0.0 and body["max_tokens"] == 64
    assert "tools" not in body and "response_format" not in body
    assert reply.message == {"role": "assistant", "content": "On the drying rack."}


def test_tool_calls_come_back_in_openai_shape():
    tools = [{"type": "function", "function": {"name": "search", "description": "search memory",
                                               "parameters": {"type": "object", "properties": {"query": {"type": "string"}},
                                                              "required": ["query"]}}}]
    calls = [tool_call("search", {"query": "red mug"}, id="call_1")]
    with ScriptedServer([Turn(content=None, tool_calls=calls)]) as server:
        reply = openai_backend(server).chat(MESSAGES, role="answer", tools=tools, tool_choice="auto")
    assert reply.content == ""
    assert reply.finish_reason == "tool_calls"
    assert reply.tool_calls == calls
    assert json.loads(reply.tool_calls[0]["function"]["arguments"]) == {"query": "red mug"}
    assert server.requests[0]["tools"] == tools
    assert server.requests[0]["tool_choice"] == "auto"
    assert reply.message["tool_calls"] == calls


def test_multimodal_content_parts_pass_through_unchanged():
    jpeg = b"\xff\xd8\xff\xe0fake-jpeg"
    wav = b"RIFF....WAVEfmt "
    content = [text_part("Describe the segment."), image_part(jpeg), audio_part(wav)]
    with ScriptedServer(["A person rinses a mug."]) as server:
        openai_backend(server).chat([{"role": "user", "content": content}], role="perception")
    sent = server.requests[0]["messages"][0]["content"]
    assert sent == content
    assert sent[1]["image_url"]["url"].startswith("data:image/jpeg;base64,")
    assert sent[2] == {"type": "input_audio", "input_audio": {"data": "UklGRi4uLi5XQVZFZm10IA==", "format": "wav"}}


def test_model_defaults_to_the_first_model_the_server_lists():
    with ScriptedServer(["hi"], models=("Qwen/Qwen3-30B-A3B-Instruct-2507", "other")) as server:
        backend = get_backend("openai", base_url=server.base_url)
        assert backend.model is None
        backend.chat(MESSAGES, role="editor")
    assert server.requests[0]["model"] == "Qwen/Qwen3-30B-A3B-Instruct-2507"
    assert backend.call_log.records[0].model == "Qwen/Qwen3-30B-A3B-Instruct-2507"


def test_api_key_comes_from_the_environment(monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-123")
    with ScriptedServer(["ok"]) as server:
        openai_backend(server).chat(MESSAGES, role="answer")
    assert {k.lower(): v for k, v in server.headers[0].items()}["authorization"] == "Bearer sk-test-123"


def test_extra_body_reaches_the_server():
    with ScriptedServer(["ok"]) as server:
        openai_backend(server, extra_body={"chat_template_kwargs": {"enable_thinking": False}}).chat(MESSAGES, role="answer")
    assert server.requests[0]["chat_template_kwargs"] == {"enable_thinking": False}


# -- structured replies -------------------------------------------------------------------------


def test_response_model_uses_json_schema_decoding_and_validates():
    reply_text = 'Sure. Here it is:\n```json\n{"answer": "C", "evidence": ["turn 12"]}\n```\nDone.'
    with ScriptedServer([reply_text]) as server:
        reply = openai_backend(server).chat(MESSAGES, role="answer", response_model=Answer)
    assert reply.parsed == Answer(answer="C", evidence=["turn 12"])
    assert reply.repairs == 0
    fmt = server.requests[0]["response_format"]
    assert fmt["type"] == "json_schema"
    assert fmt["json_schema"]["name"] == "Answer"
    assert fmt["json_schema"]["schema"]["properties"]["answer"]["pattern"] == "^[A-E]$"


def test_json_schema_can_be_switched_off_for_servers_without_it():
    with ScriptedServer(['{"answer": "A"}']) as server:
        reply = openai_backend(server, json_schema=False).chat(MESSAGES, role="answer", response_model=Answer)
    assert reply.parsed.answer == "A"
    assert "response_format" not in server.requests[0]


def test_malformed_reply_gets_one_repair_turn_that_succeeds():
    script = [
        Turn(content='{"answer": "C", "evidence": [', usage={"prompt_tokens": 30, "completion_tokens": 8}),
        Turn(content='{"answer": "C"}', usage={"prompt_tokens": 60, "completion_tokens": 5}),
    ]
    with ScriptedServer(script) as server:
        backend = openai_backend(server)
        reply = backend.chat(MESSAGES, role="answer", response_model=Answer)
    assert reply.parsed == Answer(answer="C")
    assert reply.repairs == 1
    assert len(server.requests) == 2
    repair = server.requests[1]["messages"]
    assert repair[: len(MESSAGES)] == MESSAGES
    assert repair[-2] == {"role": "assistant", "content": '{"answer": "C", "evidence": ['}
    assert repair[-1]["role"] == "user" and "could not be used" in repair[-1]["content"]
    record = backend.call_log.records[0]
    assert record.ok and record.repairs == 1
    assert (record.tokens_in, record.tokens_out) == (90, 13)


def test_schema_violation_is_shown_to_the_model():
    with ScriptedServer(['{"answer": "Z"}', '{"answer": "B"}']) as server:
        reply = openai_backend(server).chat(MESSAGES, role="answer", response_model=Answer)
    assert reply.parsed.answer == "B"
    repair_prompt = server.requests[1]["messages"][-1]["content"]
    assert "answer" in repair_prompt and "pattern" in repair_prompt


def test_two_malformed_replies_raise_model_reply_error_with_the_raw_reply():
    with ScriptedServer(["I think the answer is C.", "It is C, definitely"]) as server:
        backend = openai_backend(server)
        with pytest.raises(ModelReplyError) as info:
            backend.chat(MESSAGES, role="editor", response_model=Answer)
    error = info.value
    assert isinstance(error, MemoraError)
    assert error.raw_reply == "It is C, definitely"
    assert error.attempts == ["I think the answer is C.", "It is C, definitely"]
    assert error.role == "editor"
    assert "editor" in str(error) and "Answer" in str(error) and "It is C, definitely" in str(error)
    assert len(server.requests) == 2  # exactly one repair turn
    record = backend.call_log.records[0]
    assert not record.ok and "ModelReplyError" in record.error and record.repairs == 1


# -- transport errors and retries ---------------------------------------------------------------


def test_server_error_then_success_is_retried():
    with ScriptedServer([Turn(status=500, error="CUDA out of memory"), "recovered"]) as server:
        backend = openai_backend(server)
        reply = backend.chat(MESSAGES, role="answer")
    assert reply.content == "recovered"
    assert reply.retries == 1
    assert len(server.requests) == 2
    assert backend.call_log.records[0].retries == 1 and backend.call_log.records[0].ok


def test_rate_limit_honours_retry_after():
    with ScriptedServer([Turn(status=429, headers={"Retry-After": "0.3"}), "ok"]) as server:
        started = time.perf_counter()
        reply = openai_backend(server).chat(MESSAGES, role="answer")
        waited = time.perf_counter() - started
    assert reply.content == "ok" and reply.retries == 1
    assert waited >= 0.3


def test_retries_give_up_after_max_retries_with_a_clear_error():
    script = [Turn(status=503, error="engine overloaded")] * 3
    with ScriptedServer(script) as server:
        backend = openai_backend(server, max_retries=2)
        with pytest.raises(ModelServerError) as info:
            backend.chat(MESSAGES, role="answer")
    assert info.value.status == 503
    assert info.value.url == f"{server.base_url}/chat/completions"
    message = str(info.value)
    assert server.base_url in message and "503" in message and "engine overloaded" in message
    assert "3 attempts" in message
    record = backend.call_log.records[0]
    assert not record.ok and record.retries == 2


def test_client_errors_are_not_retried():
    with ScriptedServer([Turn(status=400, error="response_format is not supported")]) as server:
        with pytest.raises(ModelServerError) as info:
            openai_backend(server).chat(MESSAGES, role="answer", response_model=Answer)
    assert len(server.requests) == 1
    assert "HTTP 400" in str(info.value) and "response_format is not supported" in str(info.value)
    assert "json_schema=false" in str(info.value)


def test_timeout_then_retry_succeeds():
    script = [Turn(content="too late", delay_s=1.0), Turn(content="in time")]
    with ScriptedServer(script) as server:
        backend = openai_backend(server, timeout_s=0.3)
        reply = backend.chat(MESSAGES, role="answer")
    assert reply.content == "in time"
    assert reply.retries == 1


def test_timeout_without_retries_names_the_url():
    with ScriptedServer([Turn(content="too late", delay_s=1.0)]) as server:
        with pytest.raises(ModelServerError) as info:
            openai_backend(server, timeout_s=0.2, max_retries=0).chat(MESSAGES, role="answer")
    assert server.base_url in str(info.value) and "timeout" in str(info.value)


def test_connection_refused_names_the_url():
    with socket.socket() as sock:  # a port nobody listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    # No retries: the error comes at once. (The default, 3 client retries, waits about 3.5 s first:
    # a server that is restarting gets that long to come back.)
    backend = get_backend("openai", base_url=f"http://127.0.0.1:{port}/v1", model="m", max_retries=0)
    started = time.perf_counter()
    with pytest.raises(ModelServerDownError) as info:
        backend.chat(MESSAGES, role="answer")
    assert time.perf_counter() - started < 2
    assert f"http://127.0.0.1:{port}/v1/chat/completions" in str(info.value)
    assert "connection refused" in str(info.value) and "Is the model server running?" in str(info.value)
    assert not backend.call_log.records[0].ok


def test_a_reply_that_is_not_json_is_a_server_error():
    with ScriptedServer([Turn(raw_body="<html>proxy error</html>")]) as server:
        with pytest.raises(ModelServerError) as info:
            openai_backend(server).chat(MESSAGES, role="answer")
    assert "not JSON" in str(info.value) and server.base_url in str(info.value)


def test_scripted_server_fails_clearly_when_the_script_runs_out():
    with pytest.raises(AssertionError, match="script exhausted"):
        with ScriptedServer(["only turn"]) as server:
            backend = openai_backend(server)
            backend.chat(MESSAGES, role="answer")
            with pytest.raises(ModelServerError, match="ran out of model turns"):
                backend.chat(MESSAGES, role="answer")


# -- the call log -------------------------------------------------------------------------------


def test_call_log_records_every_call(tmp_path):
    log = CallLog(tmp_path / "calls.jsonl")
    script = [
        Turn(content='{"answer": "A"}', usage={"prompt_tokens": 100, "completion_tokens": 7}, delay_s=0.05),
        Turn(status=502),
        Turn(content="plain", usage={"prompt_tokens": 40, "completion_tokens": 2}),
        Turn(content='{"answer": "B"}'),
    ]
    with ScriptedServer(script) as server:
        backend = openai_backend(server, model="Qwen/Qwen3-30B-A3B-Instruct-2507")
        backend.call_log = log
        backend.chat(MESSAGES, role="editor", response_model=Answer, tags={"segment": "P01_101:3"})
        backend.chat(MESSAGES[1:], role="answer")
        backend.chat(MESSAGES, role="editor", response_model=Answer, tags={"segment": "P01_101:4"})

    first, second, third = log.records
    expected_hash = hashlib.sha256(
        json.dumps(MESSAGES, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()
    ).hexdigest()
    assert first.prompt_hash == expected_hash == prompt_hash(MESSAGES)
    assert second.prompt_hash != first.prompt_hash and third.prompt_hash == first.prompt_hash
    assert (first.role, first.backend, first.model) == ("editor", "openai", "Qwen/Qwen3-30B-A3B-Instruct-2507")
    assert (first.tokens_in, first.tokens_out, first.retries, first.ok) == (100, 7, 0, True)
    assert first.latency_s >= 0.05
    assert first.tags == {"segment": "P01_101:3"}
    assert (second.role, second.retries, second.tokens_in) == ("answer", 1, 40)
    assert third.tokens_in is None and third.tokens_out is None  # the server reported no usage

    # Appended as JSON lines as the calls happened, and readable back.
    assert [r.model_dump() for r in CallLog.read_jsonl(tmp_path / "calls.jsonl")] == [r.model_dump() for r in log.records]
    copy = log.write_jsonl(tmp_path / "copy.jsonl", append=True)
    log.write_jsonl(copy, append=True)
    assert len(CallLog.read_jsonl(copy)) == 6

    by_role = {row["role"]: row for row in log.summary()}
    assert by_role["editor"]["calls"] == 2 and by_role["editor"]["tokens_in"] == 100
    assert by_role["answer"] == {**by_role["answer"], "calls": 1, "errors": 0, "tokens_out": 2, "retries": 1}
    latencies = sorted(r.latency_s for r in (first, third))
    assert by_role["editor"]["latency_mean_s"] == pytest.approx(sum(latencies) / 2, abs=1e-5)
    by_segment = summarize_calls(log.records, by=("segment", "role"))
    assert [(row["segment"], row["role"], row["calls"]) for row in by_segment] == [
        (None, "answer", 1), ("P01_101:3", "editor", 1), ("P01_101:4", "editor", 1)]


def test_extract_json_finds_the_object():
    assert extract_json('{"a": 1}') == {"a": 1}
    assert extract_json('<think>maybe {"a": 0}</think>\n{"a": 2}') == {"a": 2}
    assert extract_json("Result:\n```json\n[1, 2]\n```") == [1, 2]
    assert extract_json('The record is {"a": {"b": 3}} as asked.') == {"a": {"b": 3}}
    with pytest.raises(ValueError):
        extract_json("no json here")


# -- registry, offline, vllm --------------------------------------------------------------------


def test_unknown_backend_lists_the_registered_ones():
    with pytest.raises(UnknownBackendError) as info:
        get_backend("gpt5")
    assert "'gpt5'" in str(info.value)
    for name in ("offline", "openai", "vllm"):
        assert name in str(info.value)
    assert {"offline", "openai", "vllm"} <= set(list_backends())


def test_bad_options_name_the_option():
    with pytest.raises(BackendOptionsError) as info:
        get_backend("openai", timeout_s=-1)
    assert "timeout_s" in str(info.value)
    with pytest.raises(BackendOptionsError) as info:
        get_backend("openai", bse_url="http://127.0.0.1:8000/v1")
    assert "'bse_url'" in str(info.value) and "unknown option" in str(info.value) and "base_url" in str(info.value)
    with pytest.raises(BackendOptionsError, match="base_url"):
        get_backend("openai", base_url="127.0.0.1:8000")
    with pytest.raises(BackendOptionsError, match="model"):
        get_backend("vllm")


def test_fakes_register_through_the_real_registry():
    class Echo(Backend):
        name = "echo-test"

        def _complete(self, messages, *, tools, tool_choice, response_format, stats):
            from memora_graph.llm.backends import _Completion
            return _Completion(content=messages[-1]["content"], tool_calls=[], usage=None, finish_reason="stop",
                               model=None)

    register_backend("echo-test", Echo, OfflineOptions)
    try:
        with pytest.raises(MemoraError, match="already registered"):
            register_backend("echo-test", Echo, OfflineOptions)
        backend = get_backend("echo-test")
        assert backend.chat(MESSAGES, role="answer").content == "Where is the mug?"
        assert backend.call_log.records[0].backend == "echo-test"
    finally:
        unregister_backend("echo-test")
    assert "echo-test" not in list_backends()


def test_offline_backend_reports_capabilities_and_says_how_to_configure_a_model():
    offline = get_backend("offline")
    assert offline.name == "offline"
    assert offline.supports("editor") and offline.supports("answer")
    assert not offline.supports("perception")
    with pytest.raises(ModelUnavailableError) as info:
        offline.require("perception")
    message = str(info.value)
    assert "'perception'" in message and "--backend openai --base-url" in message and "--model" in message
    for role in ("perception", "answer"):
        with pytest.raises(ModelUnavailableError, match=role):
            offline.chat(MESSAGES, role=role)
    assert len(offline.call_log) == 0


def test_vllm_not_installed_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "vllm", None)  # makes `import vllm` fail even where it exists
    with pytest.raises(ModelUnavailableError) as info:
        get_backend("vllm", model="Qwen/Qwen3.6-35B-A3B")
    assert "pip install 'memora-graph[vllm]'" in str(info.value)


def test_importing_the_backends_never_imports_vllm(tmp_path):
    (tmp_path / "vllm.py").write_text("raise SystemExit('vllm was imported')\n")
    code = "import sys, memora_graph.llm; print(sorted(memora_graph.llm.list_backends())); print('vllm' in sys.modules)"
    env = {"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("\n")[:2] == ["['offline', 'openai', 'vllm']", "False"]


def test_vllm_engine_is_loaded_once_and_kept_resident(monkeypatch):
    built = []

    class FakeLLM:
        def __init__(self, **kwargs):
            built.append(kwargs)

        def chat(self, messages, sampling_params, **kwargs):
            generated = types.SimpleNamespace(text='{"answer": "D"}', token_ids=[1, 2, 3], finish_reason="stop")
            return [types.SimpleNamespace(prompt_token_ids=[0] * 11, outputs=[generated])]

    fake = types.ModuleType("vllm")
    fake.LLM = FakeLLM
    fake.SamplingParams = lambda **kwargs: kwargs
    fake_params = types.ModuleType("vllm.sampling_params")
    fake_params.StructuredOutputsParams = lambda **kwargs: kwargs
    monkeypatch.setitem(sys.modules, "vllm", fake)
    monkeypatch.setitem(sys.modules, "vllm.sampling_params", fake_params)
    from memora_graph.llm import vllm_backend
    monkeypatch.setattr(vllm_backend, "_ENGINES", {})

    first = get_backend("vllm", model="fake/model-resident")
    second = get_backend("vllm", model="fake/model-resident")
    reply = first.chat(MESSAGES, role="answer", response_model=Answer)
    second.chat(MESSAGES, role="answer")
    assert reply.parsed == Answer(answer="D")
    assert len(built) == 1 and built[0]["model"] == "fake/model-resident"
    record = first.call_log.records[0]
    assert (record.backend, record.tokens_in, record.tokens_out) == ("vllm", 11, 3)
