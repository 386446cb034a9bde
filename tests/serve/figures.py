"""Figures of `memora serve` under a stalling request (docs/serving.md, "Time budget and caps"):

    python tests/serve/figures.py BANK PARTICIPANT [--rounds 6]

Starts `memora serve BANK --participant P --transport http --call-timeout 2` (with the test-only
`test_spin` tool) and prints, over the official mcp client on loopback:
1. 8 clients making normal calls, alone: median and max seconds per call;
2. the same while a ninth client sends a 1 MB `ask`, `search` and `plan`: the seconds until each
   1 MB call is refused, and the 8 clients' median and max;
3. a call that spins in Python for 60 s: the seconds until it is answered "took too long", the
   max seconds of `tools/list` meanwhile, the first call after it (it reopens the view), and the
   server's CPU-seconds in the second after (0: the work stopped).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import anyio
from mcp import Client, MCPError

from memora_graph.cli.perf.serve import ServerProcess

MB = "where is the knife " * (2**20 // 19)
NORMAL = [("search_objects", {"query": "knife"}), ("search", {"query": "wash the plate"}),
          ("get_preferences", {"query": "cup"}), ("get_routine_skill", {"goal_query": "wash the plate"})]


async def timed(client: Client, name: str, args: dict) -> tuple[float, object]:
    t = time.monotonic()
    try:
        out = await client.call_tool(name, args)
    except MCPError as exc:
        out = exc
    return time.monotonic() - t, out


async def clients(url: str, rounds: int, attack: bool) -> tuple[list[float], dict[str, float]]:
    normal: list[float] = []
    big: dict[str, float] = {}

    async def worker(i: int) -> None:
        async with Client(url) as client:
            await client.call_tool(*NORMAL[i % 4])
            for k in range(rounds):
                took, out = await timed(client, *NORMAL[(i + k) % 4])
                assert not isinstance(out, MCPError) and not out.is_error, out
                normal.append(took)

    async def attacker() -> None:
        async with Client(url) as client:
            for name, args in (("ask", {"question": MB}), ("search", {"query": MB}), ("plan", {"goal": MB})):
                took, out = await timed(client, name, args)
                assert isinstance(out, MCPError), out
                big[name] = took

    async with anyio.create_task_group() as tg:
        for i in range(8):
            tg.start_soon(worker, i)
        if attack:
            tg.start_soon(attacker)
    return normal, big


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("bank")
    ap.add_argument("participant")
    ap.add_argument("--rounds", type=int, default=6)
    a = ap.parse_args()
    os.environ["MEMORA_TEST_SPIN_TOOL"] = "1"
    server = ServerProcess(a.bank, a.participant, "--call-timeout", "2")
    try:
        alone, _ = anyio.run(clients, server.url, a.rounds, False)
        print(f"8 clients alone: median {statistics.median(alone):.3f} s, max {max(alone):.3f} s per call "
              f"({len(alone)} calls)")
        under, big = anyio.run(clients, server.url, a.rounds, True)
        print("1 MB refused after: " + ", ".join(f"{k} {v:.3f} s" for k, v in big.items()))
        print(f"8 clients meanwhile: median {statistics.median(under):.3f} s, max {max(under):.3f} s per call")

        async def stall() -> tuple[float, str, list[float], float]:
            lists: list[float] = []
            spun: list = []
            async with Client(server.url) as c1, Client(server.url) as c2:
                async def spin() -> None:
                    spun.append(await timed(c1, "test_spin", {"seconds": 60}))

                async def poll() -> None:
                    await anyio.sleep(0.2)
                    while not spun:
                        t = time.monotonic()
                        await c2.list_tools()
                        lists.append(time.monotonic() - t)
                        await anyio.sleep(0.1)

                async with anyio.create_task_group() as tg:
                    tg.start_soon(spin)
                    tg.start_soon(poll)
                after, _ = await timed(c2, "search_objects", {"query": "knife"})
            took, out = spun[0]
            return took, out.content[0].text[:60], lists, after

        took, text, lists, after = anyio.run(stall)
        cpu = server.cpu_seconds()
        time.sleep(1.0)
        idle = (server.cpu_seconds() - cpu) if cpu is not None else float("nan")
        print(f"a 60 s call, budget 2 s: answered after {took:.3f} s ({text!r}); tools/list meanwhile max "
              f"{max(lists):.3f} s ({len(lists)} calls); the next call {after:.3f} s; server CPU in the second "
              f"after {idle:.3f} s")
    finally:
        server.stop()


if __name__ == "__main__":
    main()
