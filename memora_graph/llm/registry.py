"""The backend registry: backends by name, with options validated by each backend's pydantic model."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from pydantic import BaseModel, ValidationError

from memora_graph.llm.base import Backend
from memora_graph.llm.calllog import CallLog
from memora_graph.llm.errors import BackendOptionsError, ModelError, UnknownBackendError
from memora_graph.llm.offline import OfflineBackend, OfflineOptions
from memora_graph.llm.openai_backend import OpenAIBackend, OpenAIOptions
from memora_graph.llm.vllm_backend import VLLMBackend, VLLMOptions


@dataclass(frozen=True)
class BackendEntry:
    name: str
    factory: Callable[..., Backend]  # factory(options, call_log) -> Backend
    options_model: type[BaseModel]


_REGISTRY: dict[str, BackendEntry] = {}


def register_backend(name: str, factory: Callable[..., Backend], options_model: type[BaseModel],
                     *, replace: bool = False) -> None:
    """Register a backend. `factory(options, call_log)` receives validated options."""
    if name in _REGISTRY and not replace:
        raise ModelError(f"A backend named {name!r} is already registered")
    _REGISTRY[name] = BackendEntry(name, factory, options_model)


def unregister_backend(name: str) -> None:
    _REGISTRY.pop(name, None)


def list_backends() -> list[str]:
    return sorted(_REGISTRY)


def backend_options(name: str) -> type[BaseModel]:
    """The options model of a backend (for CLIs and documentation)."""
    return _entry(name).options_model


def _entry(name: str) -> BackendEntry:
    try:
        return _REGISTRY[name]
    except KeyError:
        raise UnknownBackendError(
            f"Unknown backend {name!r}. Registered backends: {', '.join(list_backends())}"
        ) from None


def get_backend(name: str, *, call_log: CallLog | None = None, **options: Any) -> Backend:
    """The backend `name` with validated options; unknown names and bad options fail clearly."""
    entry = _entry(name)
    try:
        validated = entry.options_model.model_validate(options)
    except ValidationError as exc:
        known = ", ".join(entry.options_model.model_fields)
        problems = "; ".join(
            f"option {'.'.join(str(p) for p in err['loc']) or '(options)'!r}: "
            + ("unknown option" if err["type"] == "extra_forbidden" else err["msg"])
            for err in exc.errors()
        )
        raise BackendOptionsError(
            f"Invalid options for backend {name!r}: {problems}. Options of {name!r}: {known or '(none)'}"
        ) from None
    return entry.factory(validated, call_log)


register_backend("offline", OfflineBackend, OfflineOptions)
register_backend("openai", OpenAIBackend, OpenAIOptions)
register_backend("vllm", VLLMBackend, VLLMOptions)
