"""The `vllm` backend: an in-process vLLM engine (optional extra), with turn-level batching.

Every thread that calls `chat` (one per in-flight agent loop, video or consolidation step) puts
its request on one queue; a single engine thread takes everything pending and sends it to the
engine in one `LLM.chat` over many conversations, so N loops in flight cost one batched
generate per round, not N. While a batch runs, the next one gathers. Requests that need
different `tools` (the chat template renders them) go in separate engine calls.

The engine is loaded on first use and kept resident per configuration, as in the paper's runs.
Tests pass a fake engine (`VLLMBackend(options, engine=...)`, registered under its own name):
vllm itself is never imported until an engine must be built."""

from __future__ import annotations

import importlib
import json
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from pydantic import Field

from memora_graph.llm.base import Backend, BackendOptions, CallStats, Completion
from memora_graph.llm.calllog import CallLog
from memora_graph.llm.errors import ModelServerError, ModelUnavailableError


class VLLMOptions(BackendOptions):
    model: str
    tensor_parallel_size: int = Field(1, ge=1)
    max_model_len: int = Field(32768, gt=0)
    gpu_memory_utilization: float = Field(0.85, gt=0, le=1)
    temperature: float = Field(0.0, ge=0, le=2)
    max_tokens: int = Field(2048, gt=0)
    top_p: float = Field(1.0, gt=0, le=1)
    chat_template_kwargs: dict[str, Any] = Field(default_factory=dict)  # e.g. {"enable_thinking": false}
    engine_kwargs: dict[str, Any] = Field(default_factory=dict)
    max_batch: int = Field(256, ge=1)  # conversations per engine call at most
    batch_window_s: float = Field(0.002, ge=0)  # after the first request of a batch, wait this long for others


# One resident engine per configuration for the whole process, as in the paper's runs.
_ENGINES: dict[tuple, Any] = {}
_ENGINES_LOCK = threading.Lock()


def _import_vllm():
    try:
        return importlib.import_module("vllm")
    except ImportError as exc:
        raise ModelUnavailableError(
            "The 'vllm' backend needs the vllm package, which is not installed: "
            "pip install 'memora-graph[vllm]' (on a machine with a GPU), or serve the model with "
            "`vllm serve MODEL` elsewhere and use --backend openai --base-url http://HOST:8000/v1. "
            f"(import error: {exc})"
        ) from None


@dataclass
class _Pending:
    messages: list[dict[str, Any]]
    tools: list[dict[str, Any]] | None
    response_format: dict[str, Any] | None
    done: threading.Event = field(default_factory=threading.Event)
    output: Any = None
    error: BaseException | None = None


class _Batcher:
    """One engine thread; callers block on their request's event."""

    def __init__(self, backend: "VLLMBackend"):
        self.backend = backend
        self._pending: list[_Pending] = []
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self.batches: list[int] = []  # conversations per engine call, in order (for reports and tests)

    @property
    def pending(self) -> int:
        with self._cond:
            return len(self._pending)

    def submit(self, request: _Pending) -> Any:
        with self._cond:
            self._pending.append(request)
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._loop, name="vllm-batcher", daemon=True)
                self._thread.start()
            self._cond.notify_all()
        request.done.wait()
        if request.error is not None:
            raise request.error
        return request.output

    def _loop(self) -> None:
        while True:
            with self._cond:
                if not self._cond.wait_for(lambda: self._pending, timeout=30.0):
                    self._thread = None  # idle: the next submit starts a fresh thread
                    return
            if self.backend.options.batch_window_s:
                time.sleep(self.backend.options.batch_window_s)
            with self._cond:
                batch = self._pending[: self.backend.options.max_batch]
                del self._pending[: len(batch)]
            groups: dict[str, list[_Pending]] = {}
            for request in batch:
                groups.setdefault(json.dumps(request.tools, sort_keys=True), []).append(request)
            for group in groups.values():
                self._run(group)

    def _run(self, group: list[_Pending]) -> None:
        self.batches.append(len(group))
        try:
            outputs = self.backend._generate(group)
            if len(outputs) != len(group):
                raise ModelServerError(f"the vLLM engine returned {len(outputs)} outputs for {len(group)} "
                                       "conversations", url="vllm://in-process", model=self.backend.model)
            for request, output in zip(group, outputs):
                request.output = output
        except BaseException as exc:  # every waiting caller gets the engine's error
            for request in group:
                request.error = exc
        finally:
            for request in group:
                request.done.set()


class VLLMBackend(Backend):
    """An in-process vLLM engine, loaded on first use and kept resident; concurrent calls are
    batched into one `LLM.chat`. Tool calls come back as text (Hermes / Gemma formats) for
    `memora_graph.agent.toolcalls` to parse."""

    name = "vllm"
    options: VLLMOptions

    def __init__(self, options: VLLMOptions, call_log: CallLog | None = None, *, engine: Any = None):
        super().__init__(options, call_log)
        self._given_engine = engine
        self._vllm = _import_vllm() if engine is None else None
        self.batcher = _Batcher(self)

    def _engine(self):
        if self._given_engine is not None:
            return self._given_engine
        o = self.options
        key = (o.model, o.tensor_parallel_size, o.max_model_len, o.gpu_memory_utilization,
               json.dumps(o.engine_kwargs, sort_keys=True))
        with _ENGINES_LOCK:
            if key not in _ENGINES:
                _ENGINES[key] = self._vllm.LLM(
                    model=o.model, tensor_parallel_size=o.tensor_parallel_size, max_model_len=o.max_model_len,
                    gpu_memory_utilization=o.gpu_memory_utilization, **o.engine_kwargs,
                )
            return _ENGINES[key]

    def _sampling(self, response_format):
        o = self.options
        kwargs: dict[str, Any] = dict(temperature=o.temperature, max_tokens=o.max_tokens, top_p=o.top_p)
        vllm = self._vllm or importlib.import_module("vllm")
        if response_format is not None:
            schema = response_format["json_schema"]["schema"]
            params = importlib.import_module("vllm.sampling_params")
            if hasattr(params, "StructuredOutputsParams"):  # vLLM >= 0.11
                kwargs["structured_outputs"] = params.StructuredOutputsParams(json=schema)
            elif hasattr(params, "GuidedDecodingParams"):
                kwargs["guided_decoding"] = params.GuidedDecodingParams(json=schema)
        return vllm.SamplingParams(**kwargs)

    def _generate(self, group: list[_Pending]) -> list[Any]:
        """One engine call over the conversations of `group` (which share their tools)."""
        kwargs: dict[str, Any] = {"use_tqdm": False}
        tools = group[0].tools
        if tools:
            kwargs["tools"] = tools
        if self.options.chat_template_kwargs:
            kwargs["chat_template_kwargs"] = self.options.chat_template_kwargs
        conversations = [r.messages for r in group]
        sampling = [self._sampling(r.response_format) for r in group]
        return list(self._engine().chat(conversations, sampling, **kwargs))

    def _complete(self, messages, *, tools, tool_choice, response_format, stats: CallStats) -> Completion:
        out = self.batcher.submit(_Pending(messages, tools if tools and tool_choice != "none" else None,
                                           response_format))
        generated = out.outputs[0]
        usage = {"prompt_tokens": len(out.prompt_token_ids or []), "completion_tokens": len(generated.token_ids or [])}
        return Completion(content=generated.text, tool_calls=[], usage=usage,
                          finish_reason=getattr(generated, "finish_reason", None), model=self.options.model)
