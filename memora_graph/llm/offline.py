"""The `offline` backend: no model. Callers run a role's deterministic policy instead."""

from __future__ import annotations

from typing import Any

from memora_graph.llm.base import Backend, BackendOptions, ChatReply
from memora_graph.llm.errors import ModelUnavailableError
from memora_graph.llm.roles import ROLES, configure_hint


class OfflineOptions(BackendOptions):
    pass


class OfflineBackend(Backend):
    """No model. Callers run the deterministic policy of a role when `supports(role)` is True;
    roles without one (video perception) fail up front with instructions."""

    name = "offline"

    def supports(self, role: str) -> bool:
        return role in ROLES and ROLES[role].offline_policy

    def chat(self, messages, *, role: str, **_: Any) -> ChatReply:
        self.require(role)
        raise ModelUnavailableError(
            f"The offline backend cannot answer free-form prompts (role {role!r}); callers run the "
            f"deterministic {role} policy instead. To use a model for this role, {configure_hint(role)}."
        )

    async def achat(self, messages, *, role: str, **kwargs: Any) -> ChatReply:
        return self.chat(messages, role=role, **kwargs)
