"""Tool calls out of a model reply, whatever format the model wrote them in.

The ReAct agent gets either native OpenAI `tool_calls` (a server with a tool parser) or text
(an in-process engine, a server without one, or a model that ignores the tool protocol). The
formats, tried in this priority order and the first that yields a call wins:

1. `<tool_call>{"name": ..., "arguments": {...} or "<json string>"}</tool_call>` (Qwen/Hermes),
   with a rescue of broken JSON and of a corrupted `<function=NAME", "arguments": {...}`;
2. a fenced ```tool_call / ```json / bare ``` block, or a bare JSON object, with name and arguments;
3. Hermes XML `<function=NAME><parameter=k>v</parameter></function>`;
4. Gemma `call:name{k:v,...}` (string values may be wrapped in `<escape>` or `<|"|>`);
5. plain text `search("q")`, `get_state_at_time(120)`, ... for the tools the caller offers.

Calls to tools the caller did not offer are dropped; the rest are de-duplicated on
(name, canonical arguments), capped (3 per response by default) and normalized to `ToolCall`.
"""

from __future__ import annotations

import ast
import hashlib
import json
import re
from typing import Any, Iterable

from pydantic import BaseModel, ConfigDict

from memora_graph.retrieve.registry import first_arguments

MAX_CALLS_PER_RESPONSE = 3

class ToolCall(BaseModel):
    """One tool call in the shape the agent executes: name, decoded arguments, call id."""

    model_config = ConfigDict(frozen=True)

    name: str
    arguments: dict[str, Any]
    id: str

    @property
    def key(self) -> tuple[str, str]:
        """(name, canonical JSON of the arguments): equal for calls that would do the same thing."""
        return self.name, canonical_arguments(self.arguments)

    def to_openai(self) -> dict[str, Any]:
        """The OpenAI `tool_calls` entry for the assistant message of the conversation."""
        return {"id": self.id, "type": "function",
                "function": {"name": self.name, "arguments": json.dumps(self.arguments, ensure_ascii=False)}}


def canonical_arguments(arguments: dict[str, Any]) -> str:
    return json.dumps(arguments, sort_keys=True, separators=(",", ":"), ensure_ascii=False)


# ---------------------------------------------------------------------------------------------
# Public entry points


def parse_tool_calls(
    content: str | None,
    native: list[dict[str, Any]] | None = None,
    *,
    available: Iterable[str | dict[str, Any]] | None = None,
    max_calls: int = MAX_CALLS_PER_RESPONSE,
) -> list[ToolCall]:
    """The tool calls of one model reply.

    content    the reply text
    native     the reply's OpenAI `tool_calls` field (used first when present)
    available  the offered tools: names, or OpenAI tool schemas (their first required
               parameter receives a positional plain-text argument). None accepts any name in
               structured formats and the MEMORA tool names in plain text.
    max_calls  cap after de-duplication
    """
    tools = _Tools(available)
    found: list[tuple[str, dict[str, Any], str | None]] = []
    if native:
        found = _from_native(native, tools)
    if not found and content:
        text = _strip_blocks(content, _THINK, _TOOL_RESPONSE)
        for stage in (_from_tool_call_tags, _from_json_blocks, _from_hermes_xml, _from_gemma, _from_plain_text):
            found = [c for c in stage(text, tools) if tools.accepts(c[0])]
            if found:
                break
    calls: list[ToolCall] = []
    seen: set[tuple[str, str]] = set()
    for name, arguments, call_id in found:
        name = tools.canonical(name)
        key = (name, canonical_arguments(arguments))
        if key in seen:
            continue
        seen.add(key)
        digest = hashlib.sha256(f"{key[0]}:{key[1]}".encode()).hexdigest()[:10]
        calls.append(ToolCall(name=name, arguments=arguments, id=call_id or f"call_{len(calls)}_{digest}"))
        if len(calls) >= max_calls:
            break
    return calls


def strip_tool_markup(text: str | None) -> str:
    """The reply without tool-call / tool-response markup and without <think> blocks, for
    reading an answer or a plan out of it."""
    if not text:
        return ""
    out = _strip_blocks(text, _THINK, _TOOL_RESPONSE, _TOOL_CALL_BLOCK, _GEMMA_WRAPPED, _HERMES_FUNCTION)
    out = _FENCE.sub(lambda m: "" if _is_call_fence(m) else m.group(0), out)
    out = _remove_gemma_calls(out)
    out = _remove_bare_json_calls(out)
    out = _STRAY_TAGS.sub("", out)
    out = re.sub(r"[ \t]+\n", "\n", out)
    return re.sub(r"\n{3,}", "\n\n", out).strip()


# ---------------------------------------------------------------------------------------------
# Offered tools


class _Tools:
    def __init__(self, available: Iterable[str | dict[str, Any]] | None):
        self.open = available is None
        known = first_arguments()  # every registered tool's positional argument (its ToolSpec)
        self.first: dict[str, str] = dict(known) if available is None else {}
        self.names: dict[str, str] = {}  # lowercase -> offered name
        for item in available or []:
            name, first = _tool_name_and_first_parameter(item)
            self.names[name.lower()] = name
            self.first[name] = first or known.get(name, "query")
        if self.open:
            self.names.update({n.lower(): n for n in known})

    def canonical(self, name: str) -> str:
        return self.names.get(name.lower(), name)

    def accepts(self, name: str) -> bool:
        return self.open or name.lower() in self.names

    def plain_names(self) -> list[str]:
        return sorted(set(self.names.values()), key=len, reverse=True)

    def first_parameter(self, name: str) -> str:
        return self.first.get(self.canonical(name), "query")


def _tool_name_and_first_parameter(item: str | dict[str, Any]) -> tuple[str, str | None]:
    if isinstance(item, str):
        return item, None
    spec = item.get("function", item)
    params = spec.get("parameters") or {}
    required = params.get("required") or []
    properties = list((params.get("properties") or {}).keys())
    first = required[0] if required else (properties[0] if properties else None)
    return str(spec["name"]), first


# ---------------------------------------------------------------------------------------------
# Argument decoding (with the rescue of broken JSON)

_PAIR = re.compile(r'"([A-Za-z_][\w-]*)"\s*:\s*("(?:[^"\\]|\\.)*"|-?\d+(?:\.\d+)?|true|false|null)')
_OPEN_STRING = re.compile(r'"([A-Za-z_][\w-]*)"\s*:\s*"([^"]*)$')


def _decode_arguments(value: Any) -> dict[str, Any] | None:
    """Arguments as a dict, from a dict, a JSON string, or broken JSON; None if hopeless."""
    if value is None:
        return {}
    if isinstance(value, dict):
        return value
    if not isinstance(value, str):
        return None
    text = value.strip()
    if not text:
        return {}
    try:
        decoded = json.loads(text)
    except json.JSONDecodeError:
        decoded = _loose_literal(text)
    if isinstance(decoded, dict):
        return decoded
    if isinstance(decoded, str):  # arguments JSON-encoded twice
        return _decode_arguments(decoded) if decoded.strip().startswith("{") else None
    return _rescue_pairs(text, skip=())


def _loose_literal(text: str) -> Any:
    """Python-literal style JSON (single quotes, True/False) as some models write it."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        return None


def _rescue_pairs(text: str, skip: Iterable[str] = ("name", "arguments", "parameters")) -> dict[str, Any] | None:
    """Recover "key": value pairs from JSON too broken to decode."""
    out: dict[str, Any] = {}
    for key, raw in _PAIR.findall(text):
        if key in skip:
            continue
        try:
            out[key] = json.loads(raw)
        except json.JSONDecodeError:
            out[key] = raw.strip('"')
    tail = _OPEN_STRING.search(text.rstrip().rstrip("}").rstrip())
    if tail and tail.group(1) not in skip and tail.group(1) not in out:
        out[tail.group(1)] = tail.group(2)
    return out or None


def _call_from_object(obj: Any) -> list[tuple[str, dict[str, Any], str | None]]:
    """{"name", "arguments"|"parameters"} (or a list of them, or an OpenAI function call)."""
    if isinstance(obj, list):
        return [c for item in obj for c in _call_from_object(item)]
    if not isinstance(obj, dict):
        return []
    if isinstance(obj.get("function"), dict):  # {"type": "function", "function": {...}}
        return [(n, a, obj.get("id")) for n, a, _ in _call_from_object(obj["function"])]
    name = obj.get("name")
    if not isinstance(name, str) or not name.strip():
        return []
    raw_args = obj.get("arguments", obj.get("parameters", {}))
    arguments = _decode_arguments(raw_args)
    return [] if arguments is None else [(name.strip(), arguments, None)]


def _call_from_broken_json(body: str) -> list[tuple[str, dict[str, Any], str | None]]:
    """The regex rescue: a name plus whatever arguments can still be read."""
    match = re.search(r'"name"\s*:\s*"([^"]+)"', body) or re.search(r"'name'\s*:\s*'([^']+)'", body)
    corrupted = re.search(r'<function=([\w.-]+)"', body)  # <function=NAME", "arguments": {...}
    name_match = match or corrupted
    if not name_match:
        return []
    name = name_match.group(1).strip()
    args_at = re.search(r'["\'](?:arguments|parameters)["\']\s*:\s*', body)
    if not args_at:
        return [(name, {}, None)]
    rest = body[args_at.end():]
    if rest.startswith("{"):
        try:
            value, _ = json.JSONDecoder().raw_decode(rest)
            if isinstance(value, dict):
                return [(name, value, None)]
        except json.JSONDecodeError:
            pass
        closing = _match_close(rest, 0)
        if closing is not None:
            literal = _loose_literal(rest[: closing + 1])
            if isinstance(literal, dict):
                return [(name, literal, None)]
    elif rest.startswith('"'):
        try:
            value, _ = json.JSONDecoder().raw_decode(rest)
            decoded = _decode_arguments(value)
            if decoded is not None:
                return [(name, decoded, None)]
        except json.JSONDecodeError:
            pass
    rescued = _rescue_pairs(rest)
    return [(name, rescued or {}, None)]


# ---------------------------------------------------------------------------------------------
# The formats

_THINK = re.compile(r"<think>.*?(?:</think>|\Z)", re.S | re.I)
_TOOL_RESPONSE = re.compile(r"<\|?tool_response\|?>.*?(?:<\|?/?tool_response\|?>|\Z)", re.S)
_TOOL_CALL_BLOCK = re.compile(r"<tool_call>(.*?)(?:</tool_call>|(?=<tool_call>)|\Z)", re.S)
_GEMMA_WRAPPED = re.compile(r"(?:<\|tool_call>|<start_function_call>)(.*?)(?:<tool_call\|>|<end_function_call>|\Z)", re.S)
_HERMES_FUNCTION = re.compile(r"<function=([^>\s\"]+)>(.*?)(?:</function>|(?=<function=)|\Z)", re.S)
_HERMES_PARAMETER = re.compile(r"<parameter=([^>\s]+)>(.*?)(?:</parameter>|(?=<parameter=)|\Z)", re.S)
_FENCE = re.compile(r"```[ \t]*([\w-]*)[ \t]*\n?(.*?)```", re.S)
_GEMMA_CALL = re.compile(r"call:([A-Za-z_][\w.-]*)\s*\{")
_STRAY_TAGS = re.compile(r"</?tool_call>|<\|?/?tool_call\|?>|</?tool_response>|</think>|<end_function_call>")
_STRING_DELIMITERS = ("<escape>", '<|"|>')


def _strip_blocks(text: str, *patterns: re.Pattern) -> str:
    for pattern in patterns:
        text = pattern.sub("", text)
    return text


def _from_native(native: list[dict[str, Any]], tools: _Tools):
    out = []
    for item in native:
        for name, arguments, call_id in _call_from_object(item):
            if tools.accepts(name):
                out.append((name, arguments, call_id))
    return out


def _from_tool_call_tags(text: str, tools: _Tools):
    out = []
    for match in _TOOL_CALL_BLOCK.finditer(text):
        body = match.group(1).strip()
        fenced = _FENCE.fullmatch(body)
        if fenced:
            body = fenced.group(2).strip()
        if not body or (body.startswith("<function=") and _HERMES_FUNCTION.match(body)):
            continue  # Hermes XML inside <tool_call>: format 3 reads it
        try:
            calls = _call_from_object(json.loads(body))
        except json.JSONDecodeError:
            calls = _call_from_object(_loose_literal(body)) or _call_from_broken_json(body)
        out.extend(calls)
    return out


def _is_call_fence(match: re.Match) -> bool:
    lang = match.group(1).lower()
    if lang in ("tool_call", "tool_code"):
        return True
    return lang in ("json", "") and bool(_from_json_text(match.group(2)))


def _from_json_text(body: str):
    body = body.strip()
    try:
        return _call_from_object(json.loads(body))
    except json.JSONDecodeError:
        return []


def _from_json_blocks(text: str, tools: _Tools):
    out = []
    for match in _FENCE.finditer(text):
        lang, body = match.group(1).lower(), match.group(2).strip()
        if lang not in ("tool_call", "json", ""):
            continue
        calls = _from_json_text(body)
        if not calls and lang == "tool_call":
            calls = _call_from_broken_json(body)
        out.extend(calls)
    if out:
        return out
    # A bare JSON object in the prose: {"name": "search", "arguments": {...}}.
    for _, _, value in _json_objects(text):
        out.extend(_call_from_object(value))
    return out


def _from_hermes_xml(text: str, tools: _Tools):
    out = []
    for match in _HERMES_FUNCTION.finditer(text):
        arguments = {}
        for key, raw in _HERMES_PARAMETER.findall(match.group(2)):
            arguments[key.strip()] = _scalar(raw.strip())
        out.append((match.group(1).strip(), arguments, None))
    return out


def _from_gemma(text: str, tools: _Tools):
    out = []
    for match in _GEMMA_CALL.finditer(text):
        close = _match_close(text, match.end() - 1, single_quotes=False)
        body = text[match.end(): close] if close is not None else text[match.end():]
        arguments = _gemma_object(body)
        if arguments is not None:
            out.append((match.group(1), arguments, None))
    return out


def _from_plain_text(text: str, tools: _Tools):
    names = tools.plain_names()
    if not names:
        return []
    pattern = re.compile(r"(?<![\w.])(" + "|".join(re.escape(n) for n in names) + r")\(", re.I)
    out = []
    for match in pattern.finditer(text):
        close = _match_close(text, match.end() - 1)
        if close is None:  # an apostrophe in a bare argument: fall back to the next ")"
            close = _match_close(text, match.end() - 1, single_quotes=False)
        if close is None:
            continue
        arguments = _python_call_arguments(text[match.end(): close], tools.first_parameter(match.group(1)))
        if arguments is not None:
            out.append((match.group(1), arguments, None))
    return out


# ---------------------------------------------------------------------------------------------
# Small scanners


def _match_close(text: str, open_index: int, single_quotes: bool = True) -> int | None:
    """Index of the bracket closing the one at `open_index`, skipping quoted strings and
    Gemma string delimiters; None when it is never closed."""
    pairs = {"(": ")", "[": "]", "{": "}"}
    stack = [pairs[text[open_index]]]
    i = open_index + 1
    while i < len(text):
        skipped = _skip_string(text, i, single_quotes)
        if skipped != i:
            i = skipped
            continue
        ch = text[i]
        if ch in pairs:
            stack.append(pairs[ch])
        elif stack and ch == stack[-1]:
            stack.pop()
            if not stack:
                return i
        i += 1
    return None


def _skip_string(text: str, i: int, single_quotes: bool = True) -> int:
    """If a string starts at i, the index just after it; else i. Gemma bodies and prose are
    scanned without single quotes, where an apostrophe is more likely than a string."""
    for delimiter in _STRING_DELIMITERS:
        if text.startswith(delimiter, i):
            end = text.find(delimiter, i + len(delimiter))
            return len(text) if end == -1 else end + len(delimiter)
    if text[i] == '"' or (single_quotes and text[i] == "'"):
        quote = text[i]
        j = i + 1
        while j < len(text):
            if text[j] == "\\":
                j += 2
                continue
            if text[j] == quote:
                return j + 1
            j += 1
        return len(text)
    return i


def _split_top_level(text: str, separator: str) -> list[str]:
    parts, depth, start, i = [], 0, 0, 0
    while i < len(text):
        skipped = _skip_string(text, i, single_quotes=False)
        if skipped != i:
            i = skipped
            continue
        ch = text[i]
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif ch == separator and depth == 0:
            parts.append(text[start:i])
            start = i + 1
        i += 1
    parts.append(text[start:])
    return [p for p in (p.strip() for p in parts) if p]


def _unquote(text: str) -> str | None:
    text = text.strip()
    for delimiter in _STRING_DELIMITERS:
        n = len(delimiter)
        if text.startswith(delimiter) and text.endswith(delimiter) and len(text) >= 2 * n:
            return text[n:-n]
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
        try:
            return json.loads(text) if text[0] == '"' else text[1:-1]
        except json.JSONDecodeError:
            return text[1:-1]
    return None


def _scalar(text: str) -> Any:
    """A parameter value: JSON (numbers, booleans, objects) when it parses, else the string."""
    unquoted = _unquote(text)
    if unquoted is not None:
        return unquoted
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _gemma_object(body: str) -> dict[str, Any] | None:
    arguments: dict[str, Any] = {}
    for part in _split_top_level(body, ","):
        colon = _find_top_level(part, ":")
        if colon is None:
            return None
        key = part[:colon].strip()
        arguments[_unquote(key) or key] = _gemma_value(part[colon + 1:].strip())
    return arguments


def _find_top_level(text: str, char: str) -> int | None:
    i = 0
    while i < len(text):
        skipped = _skip_string(text, i, single_quotes=False)
        if skipped != i:
            i = skipped
            continue
        if text[i] == char:
            return i
        i += 1
    return None


def _gemma_value(raw: str) -> Any:
    if raw.startswith("{") and raw.endswith("}"):
        nested = _gemma_object(raw[1:-1])
        if nested is not None:
            return nested
    if raw.startswith("[") and raw.endswith("]"):
        return [_gemma_value(item) for item in _split_top_level(raw[1:-1], ",")]
    return _scalar(raw)


def _python_call_arguments(args_text: str, first_parameter: str) -> dict[str, Any] | None:
    """Arguments of `name(...)` written in prose: literals, keywords, or bare words."""
    args_text = args_text.strip()
    if not args_text:
        return {}
    try:
        call = ast.parse(f"f({args_text})", mode="eval").body
        arguments: dict[str, Any] = {}
        if call.args:
            arguments[first_parameter] = ast.literal_eval(call.args[0])
        for keyword in call.keywords:
            if keyword.arg is None:
                return None
            arguments[keyword.arg] = ast.literal_eval(keyword.value)
        return arguments
    except (SyntaxError, ValueError, TypeError, MemoryError, RecursionError):
        pass
    value = args_text.strip().strip("\"'").strip()
    if not value:
        return None
    return {first_parameter: _number_or_text(value)}


def _number_or_text(value: str) -> Any:
    try:
        return int(value)
    except ValueError:
        try:
            return float(value)
        except ValueError:
            return value


def _remove_gemma_calls(text: str) -> str:
    while (match := _GEMMA_CALL.search(text)) is not None:
        close = _match_close(text, match.end() - 1, single_quotes=False)
        text = text[: match.start()] + (text[close + 1:] if close is not None else "")
    return text


def _json_objects(text: str):
    """Yield (start, end, value) for each JSON value that starts at a '{' in the text, left to right."""
    decoder = json.JSONDecoder()
    position = 0
    while (start := text.find("{", position)) != -1:
        try:
            value, end = decoder.raw_decode(text, start)
        except json.JSONDecodeError:
            position = start + 1
            continue
        yield start, end, value
        position = end


def _remove_bare_json_calls(text: str) -> str:
    spans = [(start, end) for start, end, value in _json_objects(text) if _call_from_object(value)]
    for start, end in reversed(spans):
        text = text[:start] + text[end:]
    return text
