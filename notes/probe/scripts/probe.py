"""Raw probe of an OpenAI-compatible server: each exchange saved as JSON under OUTDIR."""
import json, sys, time, urllib.request, urllib.error, pathlib
BASE = sys.argv[1]; OUT = pathlib.Path(sys.argv[2]); OUT.mkdir(parents=True, exist_ok=True)
opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
def ex(name, method, path, payload=None, headers=None):
    h = {"Content-Type": "application/json", **(headers or {})}
    req = urllib.request.Request(BASE + path, data=json.dumps(payload).encode() if payload is not None else None, headers=h, method=method)
    t = time.perf_counter()
    try:
        with opener.open(req, timeout=600) as r:
            status, body, hdrs = r.status, r.read().decode(), dict(r.headers)
    except urllib.error.HTTPError as e:
        status, body, hdrs = e.code, e.read().decode(), dict(e.headers)
    except Exception as e:
        status, body, hdrs = None, f"{type(e).__name__}: {e}", {}
    dt = time.perf_counter() - t
    try: parsed = json.loads(body)
    except Exception: parsed = None
    rec = {"name": name, "request": {"method": method, "path": path, "headers": headers or {}, "body": payload},
           "status": status, "seconds": round(dt, 3), "response_headers": hdrs, "response": parsed if parsed is not None else body}
    (OUT / f"{name}.json").write_text(json.dumps(rec, indent=2))
    print(f"== {name}: {status} in {dt:.2f}s\n{json.dumps(parsed, indent=1)[:1500] if parsed is not None else body[:1500]}\n")
    return rec
