"""The consolidation prompt of P09's first video, raw, in three response_format styles (max_tokens 512)."""
import json, time, sys, pathlib, urllib.request
from memora_graph.bank import Bank
from memora_graph.consolidate.memory import load_memory
from memora_graph.consolidate.llm import make_llm_processors, ConsolidationReply, CONSOLIDATION_SYSTEM
from memora_graph.llm.backends import _validate_reply
b = Bank("/work/tmp/rm/banks/cal")
with b.open("P09") as store:
    mem = load_memory(store, "P09")
procs = make_llm_processors("openai", base_url="http://x/v1", model="m")
user, handles = procs.consolidation.video_prompt(mem, mem.videos[0])
messages = [{"role": "system", "content": CONSOLIDATION_SYSTEM}, {"role": "user", "content": user}]
schema = ConsolidationReply.model_json_schema()
styles = {"none": None, "json_object": {"type": "json_object"}, "json_object_schema": {"type": "json_object", "schema": schema}}
opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
for name in sys.argv[1].split(","):
    payload = {"model": "smollm2-135m", "messages": messages, "temperature": 0, "max_tokens": int(sys.argv[2])}
    if styles[name]: payload["response_format"] = styles[name]
    t = time.perf_counter()
    with opener.open(urllib.request.Request("http://127.0.0.1:18441/v1/chat/completions", data=json.dumps(payload).encode(), headers={"Content-Type": "application/json"}), timeout=900) as r:
        data = json.loads(r.read())
    dt = time.perf_counter() - t
    content = data["choices"][0]["message"]["content"]
    try:
        _validate_reply(content, ConsolidationReply); verdict = "valid"
    except ValueError as e:
        verdict = str(e)[:300]
    rec = {"style": name, "seconds": round(dt, 1), "usage": data["usage"], "finish_reason": data["choices"][0]["finish_reason"], "verdict": verdict, "content": content}
    pathlib.Path(f"/work/wt/realmodel/notes/probe/consolidation_{name}_{sys.argv[2]}.json").write_text(json.dumps({"request": payload, **rec}, indent=2))
    print(json.dumps({k: (v[:600] if isinstance(v, str) else v) for k, v in rec.items()}, indent=1), flush=True)
