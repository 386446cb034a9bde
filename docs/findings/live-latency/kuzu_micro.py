"""What a small Kùzu write costs (CPU per transaction): an empty transaction, one CREATE, a 384-float
vector column, a primary-key MATCH and SET; run: python kuzu_micro.py /tmp/micro.kuzu"""
import kuzu, time, sys, os, numpy as np
p = sys.argv[1] if len(sys.argv) > 1 else "/tmp/kuzu-micro.kuzu"
for f in [p, p + ".wal"]:
    if os.path.exists(f): os.remove(f)
db = kuzu.Database(p); c = kuzu.Connection(db)
c.execute("CREATE NODE TABLE T(id STRING, a STRING, b INT64, emb FLOAT[384], PRIMARY KEY(id))")
c.execute("CREATE NODE TABLE U(id STRING, a STRING, b INT64, PRIMARY KEY(id))")
c.execute("CREATE NODE TABLE L(id STRING, a STRING, b INT64, emb FLOAT[], PRIMARY KEY(id))")
emb = np.random.rand(384).astype(np.float32).tolist()
def bench(name, q, mk, n=300):
    ps = c.prepare(q)
    c0 = time.process_time()
    for i in range(n):
        c.execute("BEGIN TRANSACTION")
        c.execute(ps, mk(i))
        c.execute("COMMIT")
    print(f"{name:40s} {(time.process_time()-c0)/n*1e3:.3f} ms/tx")
def empty(n=300):
    c0 = time.process_time()
    for i in range(n):
        c.execute("BEGIN TRANSACTION"); c.execute("COMMIT")
    print(f"{'empty tx':40s} {(time.process_time()-c0)/n*1e3:.3f} ms/tx")
empty()
bench("T with emb", "CREATE (:T {id: $id, a: $a, b: $b, emb: $emb})", lambda i: {"id": f"x{i}", "a": "hello", "b": i, "emb": emb})
bench("T without emb", "CREATE (:T {id: $id, a: $a, b: $b})", lambda i: {"id": f"y{i}", "a": "hello", "b": i})
bench("U", "CREATE (:U {id: $id, a: $a, b: $b})", lambda i: {"id": f"y{i}", "a": "hello", "b": i})
bench("L list emb", "CREATE (:L {id: $id, a: $a, b: $b, emb: $emb})", lambda i: {"id": f"x{i}", "a": "hello", "b": i, "emb": emb})
bench("U x2 in one stmt", "CREATE (:U {id: $id, a: $a, b: $b}), (:U {id: $id2, a: $a, b: $b})", lambda i: {"id": f"z{i}", "id2": f"w{i}", "a": "hello", "b": i})
bench("U match by pk + set", "MATCH (u:U {id: $id}) SET u.b = $b", lambda i: {"id": f"y{i}", "b": i + 1})
bench("U match 3 by pk + set", "MATCH (u:U {id: $id}), (v:U {id: $id2}), (w:U {id: $id3}) SET u.b = $b, v.b = $b, w.b = $b", lambda i: {"id": f"y{i}", "id2": f"y{i+1}", "id3": f"y{i+2}", "b": i + 1})
c.set_max_threads_for_exec(1)
bench("1thr: T with emb", "CREATE (:T {id: $id, a: $a, b: $b, emb: $emb})", lambda i: {"id": f"q{i}", "a": "hello", "b": i, "emb": emb})
bench("1thr: U", "CREATE (:U {id: $id, a: $a, b: $b})", lambda i: {"id": f"q{i}", "a": "hello", "b": i})
bench("1thr: U match 3 by pk + set", "MATCH (u:U {id: $id}), (v:U {id: $id2}), (w:U {id: $id3}) SET u.b = $b, v.b = $b, w.b = $b", lambda i: {"id": f"y{i}", "id2": f"y{i+1}", "id3": f"y{i+2}", "b": i + 1})
