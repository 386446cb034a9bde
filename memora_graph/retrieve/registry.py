"""The tool registry: one `ToolSpec` per tool, and everything else derived from it.

A spec names the tool, its pydantic argument model (validated before the tool runs, so a model's
malformed call fails with a message naming the argument), the argument a positional value fills,
the result model, the store it reads and its description. Specs are grouped by the memory
representation they read (`family`): "memora" (the typed stores of `memora_graph.retrieve.tools`),
and the baselines' "flat1d" and "graph2d" (`memora_graph.baselines`). From the specs come the
OpenAI function schemas an agent advertises, the tool-call parser's positional arguments, the
evaluation's tool sets (`ToolSet`), the report's tool -> store map and the `memora tool(s)`
commands. Adding a tool is one function plus its `@tool(...)` line:

    @tool("count_uses", args=QueryArgs, result=ObjectsResult, store="Entity", description="...")
    def count_uses(view, query, top_k=10):
        return Reply({"query": query, "top_k": top_k}, results=[...])

A tool returns its result, or a `Reply` (the arguments it echoes and the result's fields) that the
decorator wraps in the spec's result with the tool's name, the participant and the memory's notes.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import json
import typing
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import AliasChoices, BaseModel, ValidationError

from memora_graph.retrieve.args import Embedded
from memora_graph.retrieve.results import ToolErrorResult, ToolResult
from memora_graph.retrieve.view import ToolError

MEMORA = "memora"


@functools.lru_cache(maxsize=None)
def _schema_json(spec: "ToolSpec") -> str:
    params = spec.args.model_json_schema()
    props = {k: {kk: vv for kk, vv in v.items() if kk != "title"} for k, v in params.get("properties", {}).items()}
    return json.dumps({"type": "function", "function": {
        "name": spec.name, "description": spec.description,
        "parameters": {"type": "object", "properties": props, "required": params.get("required", [])},
    }})


@dataclass(frozen=True)
class ToolSpec:
    name: str
    description: str
    args: type[BaseModel]
    fn: Callable[..., ToolResult]  # (memory, **arguments) -> result
    result: type[ToolResult]
    store: str  # the store it reads: Entity, Activity, Environment, Inferred, unified search, ...
    family: str = MEMORA
    first: str | None = None  # the argument a positional value fills (default: the first field)
    advertised: bool = True  # listed in tool_schemas() by default

    @property
    def first_argument(self) -> str:
        return self.first or next(iter(self.args.model_fields))

    @property
    def aliases(self) -> dict[str, str]:
        """Other accepted argument names -> the argument they fill."""
        out = {}
        for name, f in self.args.model_fields.items():
            if isinstance(f.validation_alias, AliasChoices):
                out.update({a: name for a in f.validation_alias.choices if isinstance(a, str) and a != name})
        return out

    @property
    def embedded_arguments(self) -> frozenset[str]:
        """Argument names (aliases included) whose value the tool embeds as a query."""
        names = {n for n, f in self.args.model_fields.items() if any(isinstance(m, Embedded) for m in f.metadata)}
        return frozenset(names | {a for a, n in self.aliases.items() if n in names})

    def schema(self) -> dict:
        # pydantic builds a JSON schema in ~4 ms; every agent episode asks for all of them: once per spec.
        return json.loads(_schema_json(self))

    def validate(self, arguments: dict | None) -> dict:
        try:
            return self.args.model_validate(arguments or {}).model_dump()
        except ValidationError as exc:
            problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'arguments'}: {e['msg']}" for e in exc.errors())
            raise ToolError(f"{self.name}: invalid arguments ({problems})") from exc


@dataclass(frozen=True)
class Family:
    """A memory representation the tools of one family read, and how to open it for one participant."""

    name: str
    label: str
    open: Callable[[Path, str], Any]  # (bank directory, participant) -> memory


_TOOLS: dict[tuple[str, str], ToolSpec] = {}
_FAMILIES: dict[str, Family] = {}
# the modules that register the project's own tools (imported on first lookup)
_PROVIDERS = ("memora_graph.retrieve.tools", "memora_graph.baselines.flat1d", "memora_graph.baselines.graph2d")
_loaded = False


def _load() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        for module in _PROVIDERS:
            importlib.import_module(module)


def register(spec: ToolSpec) -> ToolSpec:
    key = (spec.family, spec.name)
    if key in _TOOLS:
        raise ToolError(f"tool {spec.name!r} is already registered for {spec.family!r}")
    _TOOLS[key] = spec
    return spec


def unregister(name: str, family: str = MEMORA) -> None:
    _TOOLS.pop((family, name), None)


class Reply:
    """What a tool returns for the `@tool` decorator to wrap: the arguments the result echoes (as
    the tool read them) and the fields of its result model."""

    __slots__ = ("arguments", "body")

    def __init__(self, arguments: dict[str, Any], **body: Any) -> None:
        self.arguments, self.body = arguments, body


def tool(name: str, *, args: type[BaseModel], result: type[ToolResult], store: str, description: str,
         family: str = MEMORA, first: str | None = None, advertised: bool = True):
    """Register the decorated function as a tool. The decorator returns it wrapped: a `Reply` it
    returns becomes the spec's result (tool name, the memory's participant, the echoed arguments,
    the fields, and the memory's notes when it has any); a result it returns passes unchanged."""
    def deco(fn: Callable[..., ToolResult | Reply]) -> Callable[..., ToolResult]:
        @functools.wraps(fn)
        def run(memory, *a, **kw) -> ToolResult:
            out = fn(memory, *a, **kw)
            if not isinstance(out, Reply):
                return out
            notes = getattr(memory, "notes", None)
            return result(tool=name, participant=memory.participant, arguments=out.arguments, **out.body,
                          **({"notes": list(notes)} if notes else {}))

        # callers (and help()) see the result model the wrapper returns, not the Reply
        run.__annotations__ = {**fn.__annotations__, "return": result}
        run.__signature__ = inspect.signature(fn).replace(return_annotation=result)
        register(ToolSpec(name, description, args, run, result, store, family, first, advertised))
        return run
    return deco


def register_family(family: Family) -> Family:
    if family.name in _FAMILIES:
        raise ToolError(f"memory family {family.name!r} is already registered")
    _FAMILIES[family.name] = family
    return family


def get_family(name: str) -> Family:
    _load()
    if name not in _FAMILIES:
        raise ToolError(f"no memory family {name!r}; families: {', '.join(_FAMILIES)}")
    return _FAMILIES[name]


def families() -> list[str]:
    _load()
    return list(_FAMILIES)


def get_tool(name: str, family: str = MEMORA) -> ToolSpec:
    _load()
    spec = _TOOLS.get((family, name))
    if spec is None:
        raise ToolError(f"no tool {name!r}; tools: {', '.join(tool_names(family))}")
    return spec


def tool_names(family: str = MEMORA, advertised_only: bool = False) -> list[str]:
    _load()
    return [n for (f, n), s in _TOOLS.items() if f == family and (s.advertised or not advertised_only)]


def specs(family: str | None = None) -> list[ToolSpec]:
    _load()
    return [s for (f, _), s in _TOOLS.items() if family is None or f == family]


def tool_schemas(names: list[str] | None = None, family: str = MEMORA) -> list[dict]:
    """OpenAI function schemas (`tools=[...]` of a chat request) for the named tools, or for
    every advertised tool of the family."""
    return [get_tool(n, family).schema() for n in (names if names is not None else tool_names(family, True))]


def first_arguments() -> dict[str, str]:
    """Tool name -> the argument a positional value fills, over every family (a name several
    families share fills the same argument)."""
    out: dict[str, str] = {}
    for s in specs():
        out.setdefault(s.name, s.first_argument)
    return out


def store_of(tool_name: str, family: str = MEMORA) -> str:
    """The store a tool reads (the report's per-store tool use); an unknown tool is its own store."""
    _load()
    spec = _TOOLS.get((family, tool_name))
    return spec.store if spec else tool_name


def call_tool(memory, name: str, arguments: dict | None = None, family: str = MEMORA) -> ToolResult:
    """Validate `arguments` against the tool's schema and run it on the memory (for "memora", a
    `MemoryView`). Raises ToolError for an unknown tool, invalid arguments or a call the tool
    cannot answer."""
    spec = get_tool(name, family)
    return spec.fn(memory, **spec.validate(arguments))


def parse_arguments(spec: ToolSpec, raw: dict[str, str]) -> dict[str, Any]:
    """Command-line strings -> argument values: a field that takes text keeps the text, any other
    is read as JSON when it parses (numbers, booleans, lists)."""
    import json

    out: dict[str, Any] = {}
    for name, value in raw.items():
        target = spec.aliases.get(name, name)
        f = spec.args.model_fields.get(target)
        types = typing.get_args(f.annotation) or (f.annotation,) if f is not None else ()
        if f is None or str in types or f.annotation is str:
            out[name] = value
            continue
        try:
            out[name] = json.loads(value)
        except (json.JSONDecodeError, RecursionError):  # too deeply nested: let validation refuse the text
            out[name] = value
    return out


@dataclass
class ToolSet:
    """The tools of one condition bound to one participant's memory. A call's unknown arguments
    are dropped (an agent's extra keys are noise, not an error); invalid ones and calls a tool
    cannot answer come back as a `ToolErrorResult`, an observation for the agent, never a crash."""

    participant: str
    memory: Any
    tools: list[ToolSpec]
    _by_name: dict[str, ToolSpec] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._by_name = {s.name: s for s in self.tools}

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.tools]

    def schemas(self) -> list[dict[str, Any]]:
        return [s.schema() for s in self.tools]

    def query_texts(self, calls: Iterable[tuple[str, dict[str, Any]]]) -> list[str]:
        """The free-text arguments of a batch of calls, the ones their tools embed."""
        out = []
        for name, args in calls:
            spec = self._by_name.get(name)
            if spec is not None:
                embedded = spec.embedded_arguments
                out += [v for k, v in args.items() if k in embedded and isinstance(v, str)]
        return out

    def prefetch(self, calls: list[tuple[str, dict[str, Any]]]) -> None:
        """Embed the query texts of one response's calls in one batch before they run."""
        prefetch = getattr(self.memory, "prefetch", None)
        if prefetch is not None:
            prefetch(self.query_texts(calls))

    def call(self, name: str, arguments: dict[str, Any]) -> ToolResult:
        spec = self._by_name.get(name)
        if spec is None:
            return ToolErrorResult(error=f"unknown tool {name!r}; available: {', '.join(self._by_name)}")
        known = set(spec.args.model_fields) | set(spec.aliases)
        try:
            return spec.fn(self.memory, **spec.validate({k: v for k, v in arguments.items() if k in known}))
        except ToolError as exc:
            return ToolErrorResult(error=str(exc))

    def close(self) -> None:
        closer = getattr(self.memory, "close", None)
        if closer is not None:
            closer()


def tool_set(family: str, names: Iterable[str], participant: str, memory: Any) -> ToolSet:
    return ToolSet(participant, memory, [get_tool(n, family) for n in names])
