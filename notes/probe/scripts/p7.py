import json, time, urllib.request, sys
opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
prompt = "Summarize: " + "the person took the plate from the cupboard and washed it in the sink. " * 30
for rep in range(2):
  for port in (18441, 18442):
    payload = {"model": "m", "messages": [{"role": "user", "content": prompt + str(rep)}], "temperature": 0, "max_tokens": 64}
    t = time.perf_counter()
    with opener.open(urllib.request.Request(f"http://127.0.0.1:{port}/v1/chat/completions", data=json.dumps(payload).encode(), headers={"Content-Type": "application/json"}), timeout=900) as r:
        d = json.loads(r.read())
    print(port, round(time.perf_counter() - t, 2), d["usage"], flush=True)
