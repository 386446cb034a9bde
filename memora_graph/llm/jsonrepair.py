"""Structured replies: the JSON-schema `response_format`, lenient JSON extraction from a model's
reply, pydantic validation with messages meant for the model, and the one repair turn."""

from __future__ import annotations

import functools
import json
import re
from typing import Any

from pydantic import BaseModel, ValidationError

_FENCE = re.compile(r"```[ \t]*([\w-]*)[ \t]*\n?(.*?)```", re.DOTALL)
_THINK = re.compile(r"<think>.*?(?:</think>|\Z)", re.DOTALL | re.IGNORECASE)


class _NoJSON(ValueError):
    pass


def extract_json(text: str) -> Any:
    """The JSON value in a model reply: the whole reply, a ```json fence, or the first
    object/array embedded in prose. Raises ValueError when there is none.

    Raw control characters (a newline, a tab) inside strings are accepted (`strict=False`):
    llama-cpp-python's schema grammar lets a small model write them, and nothing else about
    such a reply is wrong."""
    if text is None or not text.strip():
        raise _NoJSON("the reply is empty")
    candidates = [text.strip()]
    without_think = _THINK.sub("", text).strip()
    if without_think != candidates[0]:
        candidates.append(without_think)
    for body in candidates:
        try:
            return json.loads(body, strict=False)
        except json.JSONDecodeError:
            pass
    body = candidates[-1]
    for match in _FENCE.finditer(body):
        try:
            return json.loads(match.group(2).strip(), strict=False)
        except json.JSONDecodeError:
            continue
    decoder = json.JSONDecoder(strict=False)
    for match in re.finditer(r"[\[{]", body):
        try:
            value, _ = decoder.raw_decode(body, match.start())
        except json.JSONDecodeError:
            continue
        if isinstance(value, (dict, list)):
            return value
    raise _NoJSON("the reply contains no JSON object")


def validate_reply(text: str, response_model: type[BaseModel]) -> BaseModel:
    """Parse and validate; raises ValueError with a message meant for the model to read."""
    try:
        value = extract_json(text)
    except _NoJSON as exc:
        raise ValueError(f"{exc}; reply with one JSON object and nothing else") from None
    try:
        return response_model.model_validate(value)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err['loc']) or '(root)'}: {err['msg']}" for err in exc.errors()[:10]
        )
        raise ValueError(f"the JSON does not match the schema: {problems}") from None


def json_schema_format(response_model: type[BaseModel]) -> dict[str, Any]:
    """The OpenAI `response_format` for JSON-schema constrained decoding (vLLM supports it)."""
    return {
        "type": "json_schema",
        "json_schema": {"name": response_model.__name__, "schema": json.loads(_schema_json(response_model))},
    }


@functools.lru_cache(maxsize=256)
def _schema_json(response_model: type[BaseModel]) -> str:
    # Generating a pydantic schema costs ~25 ms for a nested record: once per model, not per call.
    return json.dumps(response_model.model_json_schema())


def repair_messages(messages: list[dict[str, Any]], bad_reply: str, problem: str) -> list[dict[str, Any]]:
    """The conversation for the one repair turn: the model sees its reply and what is wrong."""
    return [
        *messages,
        {"role": "assistant", "content": bad_reply},
        {"role": "user", "content": (
            f"Your previous reply could not be used: {problem}. "
            "Reply again with only the corrected JSON object, matching the required schema."
        )},
    ]

