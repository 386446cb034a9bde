"""The openai backend's failure kinds, Retry-After, asyncio calls, and the vllm backend's batching,
against a real HTTP server on 127.0.0.1 (scripted model words) and a fake vLLM engine registered
through the backend registry."""

from __future__ import annotations

import asyncio
import threading
import time
import types

import pytest
from pydantic import BaseModel
from support.scripted_server import ScriptedServer, Turn

from memora_graph.llm import (
    ModelAuthError, ModelContextLengthError, ModelNotServedError, ModelRateLimitedError, ModelReplyError,
    ModelServerError, ModelTimeoutError, get_backend, register_backend, unregister_backend,
)
from memora_graph.llm.vllm_backend import VLLMBackend, VLLMOptions
from memora_graph.testing.responders import agent

MESSAGES = [{"role": "user", "content": "Where is the mug?"}]


class Where(BaseModel):
    place: str


def _backend(server, **options):
    return get_backend("openai", base_url=server.base_url, **{"model": "qwen-test", "timeout_s": 5, **options})


# -- each failure kind is its own error, naming the URL and the model ----------------------------


@pytest.mark.parametrize("turn, error, words", [
    (Turn(status=404, error="The model `qwen-test` does not exist."), ModelNotServedError, ["is 'qwen-test' served", "it serves: served-a"]),
    (Turn(status=401, error="Invalid API key"), ModelAuthError, ["refused the API key", "OPENAI_API_KEY"]),
    (Turn(status=400, error="This model's maximum context length is 4096 tokens. However, you requested 5120 tokens "
                            "(3072 in the messages, 2048 in the completion)."),
     ModelContextLengthError, ["context window", "max_tokens"]),
    (Turn(status=429, error="Too many requests", headers={"Retry-After": "0.05"}), ModelRateLimitedError,
     ["rate-limiting", "gave up after 2 attempts", "--concurrency"]),
])
def test_each_failure_kind_is_named_with_url_and_model(turn, error, words):
    with ScriptedServer([turn, turn], models=("served-a",), strict=False) as server:
        backend = _backend(server, max_retries=1)
        with pytest.raises(error) as info:
            backend.chat(MESSAGES, role="answer")
    message = str(info.value)
    assert isinstance(info.value, ModelServerError)
    assert f"{server.base_url}/chat/completions" in message and "qwen-test" in message
    for word in words:
        assert word in message
    assert info.value.url == f"{server.base_url}/chat/completions" and info.value.model == "qwen-test"
    retried = error is ModelRateLimitedError
    assert len(server.requests) == (2 if retried else 1)  # client errors are not retried
    assert backend.call_log.records[0].ok is False and backend.call_log.records[0].retries == int(retried)


def test_timeout_is_its_own_error():
    with ScriptedServer([Turn(content="late", delay_s=1.0)]) as server:
        with pytest.raises(ModelTimeoutError) as info:
            _backend(server, timeout_s=0.2, max_retries=0).chat(MESSAGES, role="answer")
    assert server.base_url in str(info.value) and "qwen-test" in str(info.value) and "timeout_s" in str(info.value)


@pytest.mark.parametrize("status", [429, 503])
def test_retry_after_is_honoured(status):
    with ScriptedServer([Turn(status=status, error="busy", headers={"Retry-After": "1"}), "ok"]) as server:
        backend = _backend(server)
        reply = backend.chat(MESSAGES, role="answer")
        gap = server.arrivals[1] - server.arrivals[0]
    assert reply.content == "ok" and reply.retries == 1 and backend.call_log.records[0].retries == 1
    assert gap >= 1.0  # the client's own backoff would have been 0.5 s at most


def test_malformed_replies_get_one_repair_turn_then_a_recorded_failure(tmp_path):
    from memora_graph.llm import CallLog

    log = CallLog(tmp_path / "calls.jsonl")
    with ScriptedServer(["the sink, I think", '{"spot": "sink"}']) as server:
        backend = get_backend("openai", base_url=server.base_url, model="m", call_log=log)
        with pytest.raises(ModelReplyError) as info:
            backend.chat(MESSAGES, role="editor", response_model=Where)
    assert len(server.requests) == 2 and "could not be used" in server.requests[1]["messages"][-1]["content"]
    assert info.value.attempts == ["the sink, I think", '{"spot": "sink"}']
    (record,) = CallLog.read_jsonl(tmp_path / "calls.jsonl")
    assert not record.ok and record.repairs == 1 and "ModelReplyError" in record.error


# -- asyncio: AsyncOpenAI behind achat -----------------------------------------------------------


def test_achat_runs_many_calls_in_flight_with_the_async_client():
    messages = [[{"role": "user", "content": f"Question: item {i}\n\nOptions:\nA) x\nB) y"}] for i in range(16)]
    with ScriptedServer(responder=agent, latency_s=0.2) as server:
        backend = _backend(server)

        async def main():
            return await asyncio.gather(*(backend.achat(m, role="answer") for m in messages))

        replies = asyncio.run(main())
        stats = server.stats()
    assert stats["inflight_max"] == 16
    assert [r.content for r in replies] == [agent({"messages": m}).content for m in messages]
    assert len(backend.call_log) == 16 and all(r.server_s >= 0.2 for r in backend.call_log.records)


# -- vllm: the pending turns of all in-flight loops go to the engine together ---------------------


class FakeEngine:
    """Stands in for vllm.LLM: records each chat() batch. The first call waits until every other
    caller is queued, so what follows must be one batch of all of them."""

    def __init__(self, backend_ref, expected):
        self.batches: list[list] = []
        self.kwargs: list[dict] = []
        self.backend_ref = backend_ref
        self.expected = expected

    def chat(self, conversations, sampling_params, **kwargs):
        assert isinstance(conversations[0], list) and len(sampling_params) == len(conversations)
        if not self.batches:
            deadline = time.monotonic() + 10
            while (self.backend_ref[0].batcher.pending < self.expected - len(conversations)
                   and time.monotonic() < deadline):
                time.sleep(0.005)
        self.batches.append(conversations)
        self.kwargs.append(kwargs)
        outs = []
        for conv in conversations:
            text = '{"place": "%s"}' % conv[-1]["content"].split()[-1]
            generated = types.SimpleNamespace(text=text, token_ids=[1, 2], finish_reason="stop")
            outs.append(types.SimpleNamespace(prompt_token_ids=[0] * 7, outputs=[generated]))
        return outs


def test_vllm_backend_batches_the_turns_of_concurrent_callers(monkeypatch):
    import sys

    fake_vllm = types.ModuleType("vllm")
    fake_vllm.SamplingParams = lambda **kwargs: kwargs
    fake_params = types.ModuleType("vllm.sampling_params")
    fake_params.StructuredOutputsParams = lambda **kwargs: kwargs
    monkeypatch.setitem(sys.modules, "vllm", fake_vllm)
    monkeypatch.setitem(sys.modules, "vllm.sampling_params", fake_params)
    n = 12
    ref: list = []
    engine = FakeEngine(ref, n)

    def factory(options, call_log):
        ref.append(VLLMBackend(options, call_log, engine=engine))
        return ref[-1]

    register_backend("fake-vllm-test", factory, VLLMOptions)
    try:
        backend = get_backend("fake-vllm-test", model="fake/model", batch_window_s=0)
        replies: dict[int, object] = {}

        def loop(i):
            replies[i] = backend.chat([{"role": "user", "content": f"where is thing{i}"}], role="answer",
                                      response_model=Where)

        threads = [threading.Thread(target=loop, args=(i,)) for i in range(n)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(20)
    finally:
        unregister_backend("fake-vllm-test")
    # Whatever the first engine call got (all n, if they queued before the engine thread woke),
    # everything that queued meanwhile went in one second call: never one call per conversation.
    assert len(engine.batches) in (1, 2) and sum(len(b) for b in engine.batches) == n
    assert backend.batcher.batches == [len(b) for b in engine.batches]
    assert {i: r.parsed.place for i, r in replies.items()} == {i: f"thing{i}" for i in range(n)}
    assert len(backend.call_log) == n and {r.tokens_in for r in backend.call_log.records} == {7}
