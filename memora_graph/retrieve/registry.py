"""The tool registry: names, argument models, and the OpenAI function schemas an agent advertises.

Arguments are validated by a pydantic model per tool before the tool runs, so a model's
malformed call fails with a message naming the argument. `search_objects` also accepts `name`
for `query` (the paper's planning prompt writes `search_objects(name="bowl")`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, ValidationError

from memora_graph.retrieve import tools
from memora_graph.retrieve.search import DEFAULT_TOP_K, MAX_TOP_K
from memora_graph.retrieve.view import MemoryView, ToolError


class _Args(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class QueryArgs(_Args):
    query: str = Field(description="What to look for, in words.")
    top_k: int = Field(DEFAULT_TOP_K, ge=1, le=MAX_TOP_K, description="How many records to return.")


class ObjectArgs(_Args):
    query: str = Field(validation_alias=AliasChoices("query", "name", "object"),
                       description="The object, in words (name, colour, material, where it is).")
    top_k: int = Field(DEFAULT_TOP_K, ge=1, le=MAX_TOP_K, description="How many objects to return.")


class SearchArgs(_Args):
    query: str = Field(description="What to look for, in words.")
    category: str | None = Field(None, description="Only one store: objects, activities, places or patterns.")
    top_k_per_category: int = Field(3, ge=1, le=MAX_TOP_K, description="How many records per store.")


class HistoryArgs(_Args):
    object_query: str = Field(validation_alias=AliasChoices("object_query", "query", "name", "object"),
                              description="The object whose history to return (id or name).")
    max_entries: int = Field(60, ge=1, le=1000, description="Most recent history entries to include.")


class StateArgs(_Args):
    time_seconds: float = Field(ge=0, allow_inf_nan=False, description="Seconds from the start of the video.")
    video: str | None = Field(None, description="The video id (e.g. P03_101); optional if the memory has one video.")
    window: float = Field(60.0, ge=0, allow_inf_nan=False, description="Seconds after an object's last sighting it still counts as present.")


class RoutineArgs(_Args):
    goal_query: str = Field(validation_alias=AliasChoices("goal_query", "query", "goal"),
                            description="The goal, e.g. 'wash the bowl'.")
    top_k: int = Field(3, ge=1, le=MAX_TOP_K, description="How many routines to return.")


class PreferenceArgs(_Args):
    query: str = Field("", description="What the preference is about; empty returns the most confident ones.")
    top_k: int = Field(5, ge=1, le=MAX_TOP_K, description="How many preferences to return.")


@dataclass(frozen=True)
class ToolSpec:
    name: str
    description: str
    args: type[_Args]
    fn: Callable[..., dict]
    advertised: bool = True  # listed in tool_schemas() by default

    def schema(self) -> dict:
        params = self.args.model_json_schema()
        props = {k: {kk: vv for kk, vv in v.items() if kk != "title"} for k, v in params.get("properties", {}).items()}
        return {"type": "function", "function": {
            "name": self.name, "description": self.description,
            "parameters": {"type": "object", "properties": props, "required": params.get("required", [])},
        }}


_TOOLS: dict[str, ToolSpec] = {}


def register(spec: ToolSpec) -> None:
    if spec.name in _TOOLS:
        raise ToolError(f"tool {spec.name!r} is already registered")
    _TOOLS[spec.name] = spec


def get_tool(name: str) -> ToolSpec:
    if name not in _TOOLS:
        raise ToolError(f"no tool {name!r}; tools: {', '.join(_TOOLS)}")
    return _TOOLS[name]


def tool_names(advertised_only: bool = False) -> list[str]:
    return [n for n, s in _TOOLS.items() if s.advertised or not advertised_only]


def tool_schemas(names: list[str] | None = None) -> list[dict]:
    """OpenAI function schemas (`tools=[...]` of a chat request) for the named tools, or for
    every advertised tool."""
    return [get_tool(n).schema() for n in (names if names is not None else tool_names(advertised_only=True))]


def call_tool(view: MemoryView, name: str, arguments: dict | None = None) -> dict:
    """Validate `arguments` against the tool's schema and run it on the view."""
    spec = get_tool(name)
    try:
        args = spec.args.model_validate(arguments or {})
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'arguments'}: {e['msg']}" for e in exc.errors())
        raise ToolError(f"{name}: invalid arguments ({problems})") from exc
    return spec.fn(view, **args.model_dump())


for _spec in (
    ToolSpec("search", "Search every memory store at once (objects, activities, places, patterns) and return the top "
             "few records of each.", SearchArgs, tools.search),
    ToolSpec("search_objects", "Find objects the person has: identity, colour/material, current state and place, the "
             "places it was seen at and the objects used with it.", ObjectArgs, tools.search_objects),
    ToolSpec("get_object_history", "The state history of one object across videos: every state and location, moves, "
             "first and last seen.", HistoryArgs, tools.get_object_history),
    ToolSpec("get_state_at_time", "What was where, and in which state, at a time of a video (from the state "
             "history), with the activity and place at that moment.", StateArgs, tools.get_state_at_time),
    ToolSpec("search_activities", "Find past episodes (10 s activity records): what was done, step by step, with the "
             "actions before and after.", QueryArgs, tools.search_activities),
    ToolSpec("search_patterns", "Find consolidated patterns: storage preferences, habits, workflows, routines and "
             "recurring action sequences.", QueryArgs, tools.search_patterns),
    ToolSpec("get_routine_skill", "Routine skills for a goal: canonical steps, key objects and the episodes they "
             "come from. Call this first when planning.", RoutineArgs, tools.get_routine_skill),
    ToolSpec("get_preferences", "The person's preferences (where things are kept, habits, tool choices) relevant to a "
             "query, with their evidence.", PreferenceArgs, tools.get_preferences),
    ToolSpec("search_environment", "Find places (kitchen areas) with their zones, features and the objects there now.",
             QueryArgs, tools.search_environment, advertised=False),
):
    register(_spec)
