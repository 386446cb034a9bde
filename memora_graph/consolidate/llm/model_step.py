"""What both model processors share: the backend, the prompt limits, step reports and the one-call
helper; a reply that stays invalid after the repair turn fails its step only."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from pydantic import BaseModel

from memora_graph.consolidate.llm.prompts import PROMPT_VERSIONS, PromptLimits
from memora_graph.consolidate.processors import StepReport
from memora_graph.llm.backends import ROLES, Backend, ModelReplyError, ModelUnavailableError

# the package's name, as before the split, so that logging configured for it still applies
log = logging.getLogger("memora_graph.consolidate.llm")

DEFAULT_MODEL = ROLES["consolidation"].default_model
OFFLINE_MESSAGE = (
    "LLM consolidation needs a model server, and the 'offline' backend has none (offline banks use "
    "--processor deterministic). Serve a model with an OpenAI-compatible server, e.g. "
    f"`vllm serve {DEFAULT_MODEL}`, then run: memora consolidate BANK --processor llm --backend openai "
    f"--base-url http://127.0.0.1:8000/v1 --model {DEFAULT_MODEL}"
)


class ModelStep:
    """What both processors share: the backend, the limits, step reports and the one-call helper."""

    name = "llm"
    role = ""

    def __init__(self, backend: Backend, *, limits: PromptLimits | None = None,
                 reports: list[StepReport] | None = None,
                 on_step: Callable[[str, str], None] | None = None):
        if backend.name == "offline":
            raise ModelUnavailableError(OFFLINE_MESSAGE)
        backend.require(self.role)
        self.backend = backend
        self.limits = limits or PromptLimits()
        self.reports = reports if reports is not None else []
        self.on_step = on_step  # on_step(participant, step): progress before each model call

    def _ask(self, participant: str, step: str, kind: str, video: str, user: str, system: str,
             response_model: type[BaseModel]) -> Any:
        """One model step: the validated reply, or None (reported and logged) if it stayed invalid."""
        if self.on_step is not None:
            self.on_step(participant, step)
        tags = {"participant": participant, "video": video, "prompt": PROMPT_VERSIONS[kind], "step": step}
        messages = [{"role": "system", "content": system}, {"role": "user", "content": user}]
        try:
            reply = self.backend.chat(messages, role=self.role, response_model=response_model, tags=tags)
        except ModelReplyError as exc:
            self.reports.append(StepReport(participant, step, False, str(exc)))
            log.warning("%s: the %s step %r failed and adds no records (its failed call is logged): %s",
                        participant, self.role, step, exc)
            return None
        self.reports.append(StepReport(participant, step, True))
        return reply.parsed
