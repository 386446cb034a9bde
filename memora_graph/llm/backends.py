"""The names of memora_graph.llm in one place, for modules that import them from here.

The code lives in one module per idea: errors, roles, calllog (CallRecord, CallLog), messages
(content parts), jsonrepair (JSON extraction, validation, the repair turn), base (the Backend
interface), offline_backend / openai_backend / vllm_backend, and registry."""

from __future__ import annotations

from memora_graph.llm.base import Backend, BackendOptions, CallStats, ChatReply, Completion
from memora_graph.llm.calllog import CallLog, CallRecord, prompt_hash, summarize_calls
from memora_graph.llm.errors import (
    BackendOptionsError, ModelAuthError, ModelContextLengthError, ModelError, ModelNotServedError,
    ModelRateLimitedError, ModelReplyError, ModelServerDownError, ModelServerError, ModelTimeoutError,
    ModelUnavailableError, UnknownBackendError,
)
from memora_graph.llm.jsonrepair import extract_json, json_schema_format, repair_messages, validate_reply
from memora_graph.llm.messages import audio_part, image_part, text_part
from memora_graph.llm.offline import OfflineBackend, OfflineOptions
from memora_graph.llm.openai_backend import OpenAIBackend, OpenAIOptions
from memora_graph.llm.registry import (
    BackendEntry, backend_options, get_backend, list_backends, register_backend, unregister_backend,
)
from memora_graph.llm.roles import ROLES, RoleSpec
from memora_graph.llm.vllm_backend import VLLMBackend, VLLMOptions

__all__ = [
    "ROLES", "Backend", "BackendEntry", "BackendOptions", "BackendOptionsError", "CallLog", "CallRecord", "CallStats",
    "ChatReply", "Completion", "ModelAuthError", "ModelContextLengthError", "ModelError", "ModelNotServedError",
    "ModelRateLimitedError", "ModelReplyError", "ModelServerDownError", "ModelServerError", "ModelTimeoutError",
    "ModelUnavailableError", "OfflineBackend", "OfflineOptions", "OpenAIBackend", "OpenAIOptions", "RoleSpec",
    "UnknownBackendError", "VLLMBackend", "VLLMOptions", "audio_part", "backend_options",
    "extract_json", "get_backend", "image_part", "json_schema_format", "list_backends", "prompt_hash",
    "register_backend", "repair_messages", "summarize_calls", "text_part", "unregister_backend", "validate_reply",
]
