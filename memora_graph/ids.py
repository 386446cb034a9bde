"""Participant ids: the one rule every id that enters memora-graph must follow (a build's
--participants and narrations, `remember`, `serve`, `query` and its confinement, export, import,
forget, verify), defined here and nowhere else.

An id is 1-64 characters of ASCII letters, digits, `-` and `_`, starting with a letter or a digit
(EPIC's `P01`, or `alice`, `robot-7`, `home_2`), except the word `all` in any case (it means
every participant in `--participants all`). It is safe as a file name (the database is
`BANK/<id>.kuzu`: no `.`, `/` or leading `-`), as a command-line value and in a message. Ids
are compared as given (`Alice` and `alice` are two people). Nothing recovers a participant from
a video id: a video belongs to the participant whose database holds it.
"""

from __future__ import annotations

import re

PATTERN = r"(?![Aa][Ll][Ll](?![A-Za-z0-9_-]))[A-Za-z0-9][A-Za-z0-9_-]{0,63}"
PARTICIPANT_ID = re.compile(rf"\A{PATTERN}\Z")  # \Z: "$" would also accept "P09\n"
RULE = ("1-64 characters of ASCII letters, digits, '-' and '_', starting with a letter or digit (e.g. P01, alice, "
        "robot-7; not 'all')")
DB_FILE = re.compile(rf"\A({PATTERN})\.kuzu\Z")  # a participant's database file in a bank


def is_participant_id(name: object) -> bool:
    """Whether `name` is a participant id (see the module docstring)."""
    return isinstance(name, str) and PARTICIPANT_ID.match(name) is not None


def describe(value: object) -> str:
    """A refused id as a message shows it: an empty string, or its first characters."""
    if value == "":
        return "an empty string"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
