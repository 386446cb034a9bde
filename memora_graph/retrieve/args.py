"""Argument models of the retrieval tools (pydantic): what an agent may pass, validated before a
tool runs, so a malformed call fails with a message naming the argument.

`QueryText` marks an argument the tool embeds (a free-text query), so a tool set can embed the
queries of one agent response in one batch before its calls run. Aliases (`search_objects`
accepts `name` for `query`: the paper's planning prompt writes `search_objects(name="bowl")`) are
declared here, on the field, and nowhere else.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import AliasChoices, BaseModel, ConfigDict, Field

from memora_graph.limits import MAX_TEXT
from memora_graph.retrieve.search import DEFAULT_TOP_K, MAX_TOP_K


class Embedded:
    """Field metadata: this argument is free text the tool embeds."""


QueryText = Annotated[str, Embedded(), Field(max_length=MAX_TEXT)]  # at most 2,000 characters (limits.py)
Name = Annotated[str, Field(max_length=200)]  # a video id, a store name


class ToolArgs(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class QueryArgs(ToolArgs):
    query: QueryText = Field(description="What to look for, in words.")
    top_k: int = Field(DEFAULT_TOP_K, ge=1, le=MAX_TOP_K, description="How many records to return.")


class ObjectArgs(ToolArgs):
    query: QueryText = Field(validation_alias=AliasChoices("query", "name", "object"),
                             description="The object, in words (name, colour, material, where it is).")
    top_k: int = Field(DEFAULT_TOP_K, ge=1, le=MAX_TOP_K, description="How many objects to return.")


class SearchArgs(ToolArgs):
    query: QueryText = Field(description="What to look for, in words.")
    category: Name | None = Field(None, description="Only one store: objects, activities, places or patterns.")
    top_k_per_category: int = Field(3, ge=1, le=MAX_TOP_K, description="How many records per store.")


class HistoryArgs(ToolArgs):
    object_query: QueryText = Field(validation_alias=AliasChoices("object_query", "query", "name", "object"),
                                    description="The object whose history to return (id or name).")
    max_entries: int = Field(60, ge=1, le=1000, description="Most recent history entries to include.")


class StateArgs(ToolArgs):
    time_seconds: float = Field(ge=0, allow_inf_nan=False, description="Seconds from the start of the video.")
    video: Name | None = Field(None, description="The video id (e.g. P03_101); optional if the memory has one video.")
    window: float = Field(60.0, ge=0, allow_inf_nan=False,
                          description="Seconds after an object's last sighting it still counts as present.")


class RoutineArgs(ToolArgs):
    goal_query: QueryText = Field(validation_alias=AliasChoices("goal_query", "query", "goal"),
                                  description="The goal, e.g. 'wash the bowl'.")
    top_k: int = Field(3, ge=1, le=MAX_TOP_K, description="How many routines to return.")


class PreferenceArgs(ToolArgs):
    query: QueryText = Field("", description="What the preference is about; empty returns the most confident ones.")
    top_k: int = Field(5, ge=1, le=MAX_TOP_K, description="How many preferences to return.")


class VideoArgs(ToolArgs):
    video: Name = Field(validation_alias=AliasChoices("video", "video_id"), description="The video id, e.g. P03_101.")
    query: QueryText = Field("", description="Only the moments about this (an object or an action); empty: the "
                                             "whole video, evenly sampled.")
    top_k: int = Field(MAX_TOP_K, ge=1, le=MAX_TOP_K, description="How many activity records to return.")
