"""The model roles (the paper's model registry table, grouped by pipeline role)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RoleSpec:
    name: str
    description: str
    default_model: str
    offline_policy: bool  # True when a deterministic policy exists for the offline backend


ROLES: dict[str, RoleSpec] = {
    spec.name: spec
    for spec in (
        RoleSpec("perception", "video segment (frames, audio) to a layered record",
                 "Qwen/Qwen2.5-Omni-7B", offline_policy=False),
        RoleSpec("editor", "online memory processor: ADD / UPDATE / DELETE / NOOP entity edits",
                 "Qwen/Qwen3-30B-A3B-Instruct-2507", offline_policy=True),
        RoleSpec("consolidation", "preferences and procedures from the episodic memory",
                 "Qwen/Qwen3.6-35B-A3B", offline_policy=True),
        RoleSpec("enrichment", "generated preferences with checked supporting evidence",
                 "Qwen/Qwen3.6-35B-A3B", offline_policy=True),
        RoleSpec("answer", "answer agent: EAM-QA and planning over the memory tools",
                 "Qwen/Qwen3.6-35B-A3B", offline_policy=True),
    )
}


def configure_hint(role: str) -> str:
    model = ROLES[role].default_model if role in ROLES else "MODEL"
    return (f"configure one, e.g. `--backend openai --base-url http://127.0.0.1:8000/v1 "
            f"--model {model}` against a server started with `vllm serve {model}`, "
            f"or `--backend vllm --model {model}` with pip install 'memora-graph[vllm]'")
