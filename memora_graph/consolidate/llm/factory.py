"""The "llm" processors built from a backend (or a backend name and its options), and the check
that reaches their model servers before any work."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from memora_graph.consolidate.llm.consolidator import LLMConsolidator
from memora_graph.consolidate.llm.enricher import LLMEnricher
from memora_graph.consolidate.llm.model_step import OFFLINE_MESSAGE
from memora_graph.consolidate.llm.prompts import PromptLimits
from memora_graph.consolidate.processors import Processors, StepReport
from memora_graph.errors import MemoraError
from memora_graph.llm.backends import Backend, CallLog, ModelUnavailableError, OpenAIBackend, get_backend


def make_llm_processors(
    backend: Backend | str = "openai",
    call_log: CallLog | None = None,
    *,
    model: str | None = None,
    consolidation_model: str | None = None,
    enrichment_model: str | None = None,
    enrichment_backend: Backend | None = None,
    limits: PromptLimits | None = None,
    on_step: Callable[[str, str], None] | None = None,
    concurrency: int = 1,
    **backend_options: Any,
) -> Processors:
    """The "llm" processors. `backend` is a backend instance or a registered backend name built
    here with `backend_options` (base_url, api_key, timeout_s, ...); `consolidation_model` (or
    `model`) and `enrichment_model` (default: the same) pick the models. Every call goes to one
    call log: `call_log`, or the given backend's. `concurrency`: per-video consolidation calls in
    flight at once (the bank written does not depend on it)."""
    if concurrency < 1:
        raise MemoraError(f"--concurrency must be at least 1, got {concurrency}")
    if isinstance(backend, str):
        if backend == "offline":
            raise ModelUnavailableError(OFFLINE_MESSAGE)
        log_ = call_log if call_log is not None else CallLog()
        cons_model = consolidation_model or model
        enr_model = enrichment_model or cons_model

        def build(m: str | None) -> Backend:
            return get_backend(backend, call_log=log_, **backend_options, **({"model": m} if m else {}))

        cons = build(cons_model)
        enr = enrichment_backend or (cons if enr_model == cons_model else build(enr_model))
    else:
        if backend_options or model or consolidation_model or enrichment_model:
            raise MemoraError("make_llm_processors: with a backend instance, configure models and options on the "
                              "backend (or pass enrichment_backend); got "
                              + ", ".join(sorted({*backend_options, *(k for k, v in (
                                  ("model", model), ("consolidation_model", consolidation_model),
                                  ("enrichment_model", enrichment_model)) if v)})))
        if call_log is not None and call_log is not backend.call_log:
            raise MemoraError("make_llm_processors: the calls go to the backend's call log; give the CallLog to get_backend")
        cons, enr = backend, enrichment_backend or backend
        log_ = backend.call_log
    if enr.call_log is not log_:
        raise MemoraError("make_llm_processors: the enrichment backend must share the consolidation backend's call log")
    reports: list[StepReport] = []
    return Processors("llm", LLMConsolidator(cons, limits=limits, reports=reports, on_step=on_step),
                      LLMEnricher(enr, limits=limits, reports=reports, on_step=on_step), call_log=log_, reports=reports,
                      concurrency=concurrency)


def check_servers(processors: Processors) -> list[str]:
    """Reach every OpenAI-compatible server of the processors before any work (a server that is
    not running fails here, with its URL) and pick its model if none was named. Returns warnings,
    e.g. a named model the server does not list."""
    warnings = []
    seen = set()
    for proc in (processors.consolidation, processors.enrichment):
        backend = getattr(proc, "backend", None)
        if not isinstance(backend, OpenAIBackend) or id(backend) in seen:
            continue
        seen.add(id(backend))
        models = backend.list_models()
        if backend.model is None:
            backend.resolve_model()
        elif models and backend.model not in models:
            warnings.append(f"{backend.options.base_url} does not list model {backend.model!r} "
                            f"(it lists: {', '.join(models)}); calls may fail")
    return warnings
