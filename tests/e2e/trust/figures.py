"""The figures issue 12 asks for, measured on a copy of a small bank (P09, P37):

- escapes of the read-only path: attacks Kùzu runs on a read-only database with no guard (each
  as written, in a fresh child process on a fresh copy of the bank), and attacks that get past
  the read guard (every attack in every disguise), with and without --write;
- segmentation faults across the query corpus, without and with the guard (`memora query`);
- tracebacks across the bad inputs: the attacks through `memora query`, the bad parameters and
  paths of every command, and the bad annotation files through `memora build`.

    python tests/e2e/trust/figures.py BANK      # BANK: a built bank with P09 and P37 (it is copied)
    python tests/e2e/trust/figures.py BANK --no-baseline   # skip the unguarded runs (about 2 s each)
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # tests/, for e2e.trust.*

from click.testing import CliRunner  # noqa: E402

from memora_graph.cli import main  # noqa: E402
from memora_graph.cypher_guard import check_read_query, check_write_query  # noqa: E402
from memora_graph.errors import QueryRefused  # noqa: E402
from e2e.trust.corpus import ALLOWED, BAD_MANIFESTS, DISGUISES, FORBIDDEN, NEVER, attacks, bad_cli_inputs  # noqa: E402
from e2e.trust.test_no_tracebacks import make_scratch, outcome  # noqa: E402
from e2e.trust.test_strict_annotations import BAD_ROWS, write_csv  # noqa: E402

# Runs one statement on P09's database opened read-only, through the library's unguarded Store
# (what `memora query` did before the guard), and prints what Kùzu returned.
_UNGUARDED = """
import sys
from memora_graph.store import Store
store = Store(sys.argv[1], read_only=True)
try:
    df = store.query(sys.argv[2])
    print("EXECUTED", df.head(3).to_dicts())
except Exception as exc:
    print("REFUSED", type(exc).__name__, str(exc)[:160])
"""


# files a read may refresh: the integrity check's record of files it found unchanged
READ_CACHES = (".verified.json",)


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name not in READ_CACHES}


def fill(statement: str, bank: Path, out: Path) -> str:
    return statement.replace("{bank}", str(bank)).replace("{other}", str(bank / "P37.kuzu")).replace("{out}", str(out))


def unguarded(source: Path, work: Path, corpus) -> list[dict]:
    """Each statement on a fresh copy of the bank, in its own process: did Kùzu run it, crash, or
    change or leak anything?"""
    rows = []
    for kind, disguise, statement in corpus:
        bank, out = work / "bank", work / "out"
        shutil.rmtree(work, ignore_errors=True)
        shutil.copytree(source, bank)
        out.mkdir()
        before = digest(bank)
        text = fill(statement, bank, out)
        try:
            p = subprocess.run([sys.executable, "-c", _UNGUARDED, str(bank / "P09.kuzu"), text], capture_output=True,
                               text=True, timeout=120)
            said, code = p.stdout.strip(), p.returncode
        except subprocess.TimeoutExpired:
            said, code = "TIMEOUT", None
        after = digest(bank)
        rows.append({
            "kind": kind, "disguise": disguise, "statement": statement,
            "executed": said.startswith("EXECUTED"), "crashed": code is not None and code < 0,
            "changed_bank": after != before, "wrote_files": any(out.rglob("*")),
            "leaked_passwd": "root:" in said, "said": said[:120] if said else f"exit {code}",
        })
    shutil.rmtree(work, ignore_errors=True)
    return rows


def guard_escapes(check, corpus) -> list[str]:
    out = []
    for _, disguise, statement in corpus:
        try:
            check(fill(statement, Path("/tmp/bank"), Path("/tmp/out")))
        except QueryRefused:
            continue
        out.append(f"{disguise}: {statement}")
    return out


def cli_runs(cases) -> Counter:
    """Run `memora` in this process for each (what, argv): count tracebacks, exit codes, crashes."""
    tally: Counter = Counter()
    for what, argv in cases:
        r = CliRunner().invoke(main, argv)
        problem = outcome(r)
        tally["runs"] += 1
        if problem and problem.startswith("traceback"):
            tally["tracebacks"] += 1
            print("  TRACEBACK", what, problem[:200])
        elif problem:
            tally["other problems"] += 1
            print("  PROBLEM", what, problem, r.output[-200:])
        if "Kùzu crashed" in r.output:
            tally["segfaults"] += 1
        tally[f"exit {r.exit_code}"] += 1
    return tally


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bank", type=Path)
    ap.add_argument("--no-baseline", action="store_true")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="trust-figures-"))
    try:
        run(args.bank, tmp, baseline=not args.no_baseline)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def run(source: Path, tmp: Path, baseline: bool) -> None:
    read_corpus, write_corpus = attacks(FORBIDDEN), attacks(NEVER)
    kinds = Counter(k for k, _ in FORBIDDEN)
    print(f"corpus: {len(FORBIDDEN)} forbidden statements ({', '.join(f'{k} {n}' for k, n in kinds.items())}) x "
          f"{len(DISGUISES)} disguises = {len(read_corpus)} read-mode attacks; {len(write_corpus)} --write attacks "
          f"(all but the data writes); {len(ALLOWED)} allowed reads")

    if baseline:
        t0 = time.perf_counter()
        multi = [(k, "second statement", s) for k, s in FORBIDDEN if k != "multi"]  # each after a read, as one string
        rows = unguarded(source, tmp / "unguarded", [(k, "as written", s) for k, s in FORBIDDEN] + multi)
        base = [r for r in rows if r["disguise"] == "as written"]
        esc = [r for r in base if r["executed"] or r["changed_bank"] or r["wrote_files"] or r["leaked_passwd"]]
        print(f"\nno guard (the library's Store on a read-only database, {time.perf_counter() - t0:.0f} s):")
        for kind in kinds:
            of = [r for r in base if r["kind"] == kind]
            got = [r for r in esc if r["kind"] == kind]
            print(f"  {kind:12s} {len(got):2d} of {len(of):2d} run, write or leak: "
                  + "; ".join(r["statement"][:50] for r in got))
        print(f"  escapes: {len(esc)} of {len(base)} as written; crashed: "
              f"{sum(r['crashed'] for r in base)} of {len(base)} as written, "
              f"{sum(r['crashed'] for r in rows if r['disguise'] != 'as written')} of {len(multi)} after a read in one "
              "string")
        for r in base:
            print(f"    {'ESCAPE ' if r in esc else 'refused'} {'CRASH ' if r['crashed'] else ''}{r['kind']:10s} "
                  f"{r['statement'][:70]} -> {r['said'][:70]}")

    print("\nwith the guard:")
    read_esc, write_esc = guard_escapes(check_read_query, read_corpus), guard_escapes(check_write_query, write_corpus)
    print(f"  escapes of the read guard: {len(read_esc)} of {len(read_corpus)}; of the --write guard: "
          f"{len(write_esc)} of {len(write_corpus)}")
    for e in read_esc + write_esc:
        print("   ", e)

    bank, out = tmp / "bank", tmp / "out"
    shutil.copytree(source, bank)
    out.mkdir()
    before = digest(bank)
    query_cases = []
    for i, (kind, disguise, statement) in enumerate(read_corpus):
        scope = ["--participant", "P09"] if i % 2 else []
        query_cases.append((f"{kind} / {disguise}", ["query", str(bank), fill(statement, bank, out), *scope]))
    for kind, disguise, statement in write_corpus:
        query_cases.append((f"--write {kind} / {disguise}", ["query", str(bank), fill(statement, bank, out),
                                                             "--participant", "P09", "--write"]))
    t0 = time.perf_counter()
    attacks_tally = cli_runs(query_cases)
    allowed_tally = Counter()
    for statement in ALLOWED:
        r = CliRunner().invoke(main, ["query", str(bank), fill(statement, bank, out), "--participant", "P09"])
        allowed_tally[f"exit {r.exit_code}"] += 1
        allowed_tally["segfaults"] += "Kùzu crashed" in r.output
        if r.exit_code:
            print("  ALLOWED FAILED", statement, r.output[-200:])
    unchanged = digest(bank) == before and not any(out.rglob("*"))
    print(f"  memora query over {attacks_tally['runs']} attacks ({time.perf_counter() - t0:.0f} s): "
          f"tracebacks {attacks_tally['tracebacks']}, segfaults {attacks_tally['segfaults']}, exit 1: "
          f"{attacks_tally['exit 1']}; {len(ALLOWED)} allowed reads: exit 0 {allowed_tally['exit 0']}, segfaults "
          f"{allowed_tally['segfaults']}; bank and output folder unchanged: {unchanged}")

    scratch = tmp / "scratch"
    scratch.mkdir()
    make_scratch(scratch, bank)
    bad_tally = cli_runs(bad_cli_inputs(str(bank), str(scratch)))
    csv_cases = []
    for i, (case, rows, _, _) in enumerate(BAD_ROWS):
        folder = tmp / f"csv{i}"
        folder.mkdir()
        csv_cases.append((f"csv {case}", ["build", str(tmp / "never"), "--annotations", str(write_csv(folder, *rows)),
                                          "--quiet"]))
    csv_tally = cli_runs(csv_cases)
    total = attacks_tally["runs"] + bad_tally["runs"] + csv_tally["runs"]
    tracebacks = attacks_tally["tracebacks"] + bad_tally["tracebacks"] + csv_tally["tracebacks"]
    print(f"\ntracebacks: {tracebacks} across {total} bad inputs ({attacks_tally['runs']} attacks through memora "
          f"query, {bad_tally['runs']} bad parameters and paths ({len(BAD_MANIFESTS)} damaged manifests among them), "
          f"{csv_tally['runs']} bad annotation files through memora build); exit codes: "
          f"{dict(sorted((k, v) for k, v in (attacks_tally + bad_tally + csv_tally).items() if k.startswith('exit')))}")


if __name__ == "__main__":
    main_()
