"""Model backends for every model role, selected by name from one registry.

    from memora_graph.llm import get_backend
    backend = get_backend("openai", base_url="http://127.0.0.1:8000/v1", model="Qwen/Qwen3-30B-A3B-Instruct-2507")
    reply = backend.chat([{"role": "user", "content": "..."}], role="editor", response_model=EditOps)
    reply.parsed          # a validated EditOps
    backend.call_log      # one CallRecord per call: role, model, prompt hash, tokens, latency, retries
    await backend.achat(...)  # the same from asyncio (AsyncOpenAI for the openai backend)

One module per idea: errors, roles, calllog, messages, jsonrepair, base (the Backend interface),
offline, openai_backend (the official openai client), vllm_backend (batched engine calls), registry.
"""

from memora_graph.llm.backends import (
    ROLES,
    Backend,
    BackendOptionsError,
    ModelAuthError,
    ModelContextLengthError,
    ModelNotServedError,
    ModelRateLimitedError,
    ModelServerDownError,
    ModelTimeoutError,
    CallLog,
    CallRecord,
    ChatReply,
    ModelError,
    ModelReplyError,
    ModelServerError,
    ModelUnavailableError,
    OfflineBackend,
    OpenAIBackend,
    RoleSpec,
    UnknownBackendError,
    VLLMBackend,
    audio_part,
    backend_options,
    extract_json,
    get_backend,
    image_part,
    json_schema_format,
    list_backends,
    prompt_hash,
    register_backend,
    summarize_calls,
    text_part,
    unregister_backend,
)

__all__ = [
    "ROLES", "Backend", "BackendOptionsError", "ModelAuthError", "ModelContextLengthError",
    "ModelNotServedError", "ModelRateLimitedError", "ModelServerDownError", "ModelTimeoutError", "CallLog", "CallRecord", "ChatReply", "ModelError",
    "ModelReplyError", "ModelServerError", "ModelUnavailableError", "OfflineBackend", "OpenAIBackend",
    "RoleSpec", "UnknownBackendError", "VLLMBackend", "audio_part", "backend_options", "extract_json",
    "get_backend", "image_part", "json_schema_format", "list_backends", "prompt_hash", "register_backend",
    "summarize_calls", "text_part", "unregister_backend",
]
