"""Answer policies by name: who answers in the agent loop (`memora bench run --backend NAME`).

"offline" is the deterministic reader (memora_graph/agent/offline.py), no model; every model
backend of the `memora_graph.llm` registry answers through `ModelPolicy` under its own name.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from memora_graph.errors import MemoraError

# name -> factory(options, call_log_path) -> policy
_POLICIES: dict[str, Callable[[dict[str, Any], Path | None], Any]] = {}


def register_answer_policy(name: str, factory: Callable[[dict[str, Any], Path | None], Any]) -> None:
    if name in _POLICIES:
        raise MemoraError(f"answer policy {name!r} is already registered")
    _POLICIES[name] = factory


def _model_backends() -> list[str]:
    from memora_graph.llm import list_backends

    return [b for b in list_backends() if b not in _POLICIES]


def answer_policy_names() -> list[str]:
    """The registered policies, then every model backend (each answers through ModelPolicy)."""
    return list(_POLICIES) + _model_backends()


def is_model_policy(name: str) -> bool:
    """Whether `name` answers with a model (its options, temperature and call log apply)."""
    return name not in _POLICIES


def make_answer_policy(name: str, options: dict[str, Any] | None = None, call_log: Path | None = None):
    """The policy `name` with its options; model calls go to `call_log` (JSON lines)."""
    if name in _POLICIES:
        return _POLICIES[name](dict(options or {}), call_log)
    if name not in _model_backends():
        raise MemoraError(f"no answer policy {name!r}; registered: {', '.join(answer_policy_names())}")
    from memora_graph.agent.loop import ModelPolicy
    from memora_graph.llm import CallLog, get_backend

    return ModelPolicy(get_backend(name, call_log=CallLog(call_log) if call_log else None, **(options or {})))


def _offline(options: dict[str, Any], call_log: Path | None):
    from memora_graph.agent.offline import OfflinePolicy

    known = {"evidence_budget", "calibration"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise MemoraError(f"the offline policy has no option {', '.join(unknown)}; it takes {', '.join(sorted(known))}")
    return OfflinePolicy(**options)


register_answer_policy("offline", _offline)
