"""Bounds on what a caller may hand the library: free text (a question, a search query, a goal)
is at most MAX_TEXT characters everywhere it enters (the MCP schemas, the library's `ask`,
`plan` and retrieval tools, the commands), so that no input makes a call run for minutes."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from memora_graph.errors import DataError

MAX_TEXT = 2000  # characters of one free-text input (question, query, goal, choice, search text)
MAX_CHOICES = 4  # answer options of a multiple-choice question (A-D)
MAX_CYPHER = 20_000  # characters of one ad-hoc Cypher statement
MAX_PARAMS = 64  # $parameters of one ad-hoc Cypher statement

Text = Annotated[str, Field(max_length=MAX_TEXT)]


class TextTooLong(DataError):
    """A free-text input longer than MAX_TEXT characters; nothing ran."""


def check_text(value: str, field: str) -> str:
    """`value` if it is at most MAX_TEXT characters, else TextTooLong naming `field`."""
    if isinstance(value, str) and len(value) > MAX_TEXT:
        raise TextTooLong(f"{field} is {len(value):,} characters long; at most {MAX_TEXT:,} are accepted "
                          "(shorten it: one question, query or goal, in words)")
    return value
