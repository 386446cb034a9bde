"""Concurrency and the official openai client against the llama-cpp-python server."""
import json, time, concurrent.futures as cf, pathlib, openai
OUT = pathlib.Path("/work/wt/realmodel/notes/probe/openai_client"); OUT.mkdir(parents=True, exist_ok=True)
log = {}
c = openai.OpenAI(base_url="http://127.0.0.1:18432/v1", api_key="sekret", max_retries=0)
log["models"] = [m.model_dump() for m in c.models.list()]
t = time.perf_counter(); r = c.chat.completions.create(model="smollm2-135m", messages=[{"role": "user", "content": "Say hi."}], max_tokens=16, temperature=0)
log["plain"] = {"seconds": round(time.perf_counter() - t, 2), "reply": r.model_dump()}
for name, kwargs in [("bad_key", dict(api_key="wrong")), ]:
    try:
        openai.OpenAI(base_url="http://127.0.0.1:18432/v1", max_retries=0, **kwargs).models.list()
    except openai.APIStatusError as e:
        log[name] = {"exception": type(e).__name__, "status": e.status_code, "body": e.body, "message": e.message}
try:
    c.chat.completions.create(model="smollm2-135m", messages=[{"role": "user", "content": "x"}], response_format={"type": "json_schema", "json_schema": {"name": "X", "schema": {"type": "object"}}})
except openai.APIStatusError as e:
    log["json_schema"] = {"exception": type(e).__name__, "status": e.status_code, "body": e.body}
try:
    c.chat.completions.create(model="smollm2-135m", messages=[{"role": "user", "content": "the plate " * 2500}], max_tokens=8)
except openai.APIStatusError as e:
    log["over_ctx"] = {"exception": type(e).__name__, "status": e.status_code, "body": e.body}
r = c.chat.completions.create(model="smollm2-135m", messages=[{"role": "user", "content": "Where is the plate?"}], tools=[{"type": "function", "function": {"name": "search", "description": "search memory", "parameters": {"type": "object", "properties": {"query": {"type": "string"}}, "required": ["query"]}}}], tool_choice="auto", max_tokens=64, temperature=0)
log["tools_auto"] = r.model_dump()
r = c.chat.completions.create(model="smollm2-135m", messages=[{"role": "user", "content": "Where is the plate?"}], response_format={"type": "json_object", "schema": {"type": "object", "properties": {"place": {"type": "string"}}, "required": ["place"]}}, max_tokens=64, temperature=0)
log["json_object_schema_via_sdk"] = r.model_dump()
# concurrency: 3 at once vs one alone
def one(i):
    t = time.perf_counter()
    r = c.chat.completions.create(model="smollm2-135m", messages=[{"role": "user", "content": f"Count to {5 + i}."}], max_tokens=32, temperature=0)
    return {"i": i, "start_to_end_s": round(time.perf_counter() - t, 2), "tokens": r.usage.completion_tokens}
t0 = time.perf_counter()
with cf.ThreadPoolExecutor(3) as pool:
    log["concurrent_3"] = list(pool.map(one, range(3)))
log["concurrent_3_wall_s"] = round(time.perf_counter() - t0, 2)
t0 = time.perf_counter(); log["sequential_1"] = one(0); 
(OUT / "client_probe.json").write_text(json.dumps(log, indent=2, default=str))
print(json.dumps({k: v for k, v in log.items() if k not in ("models",)}, indent=1, default=str)[:6000])
