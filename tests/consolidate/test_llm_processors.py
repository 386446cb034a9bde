"""LLM consolidation and enrichment against a real OpenAI-compatible HTTP server on 127.0.0.1.

Only the model's words are scripted: the prompts are built from a real bank (P09 of the small
bank), replies travel over HTTP, are validated and repaired by the backend, handles are mapped
back to segment ids, invented ids are dropped, and the records land in Kùzu with their
SUPPORTED_BY edges and the calls as ModelCall nodes. Which segment a handle stands for is read
back from the prompt the model was sent (time window -> segment), not from the processor.
"""

from __future__ import annotations

import json
import logging
import re
import shutil
import subprocess
import sys

import pytest
from click.testing import CliRunner
from support.scripted_server import ScriptedServer, Turn

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.consolidate import finish_participant, get_processors, load_memory
from memora_graph.consolidate.task_records import TASK_SOURCES
from memora_graph.consolidate.llm import OFFLINE_MESSAGE, Handles, PromptLimits, StorageItem
from memora_graph.errors import ConsolidationError, MemoraError
from memora_graph.llm.backends import ModelServerError, ModelUnavailableError
from memora_graph.stats import call_stats
from memora_graph.store import Store

P = "P09"
VIDEOS = ("P09_103", "P09_104", "P09_105", "P09_106")  # the order of the per-video calls
MODEL = "scripted-qwen"


@pytest.fixture()
def bank(small_bank, tmp_path):
    src, _ = small_bank
    shutil.copytree(src, tmp_path / "bank", ignore=shutil.ignore_patterns(".staging"))
    return Bank(tmp_path / "bank")


def consolidation(storage=(), habits=(), workflows=(), sequences=()) -> str:
    return json.dumps({"storage_preferences": list(storage), "organizational_habits": list(habits),
                       "workflow_patterns": list(workflows), "action_sequences": list(sequences)})


EMPTY = consolidation()
USAGE = {"prompt_tokens": 1500, "completion_tokens": 200}

V103 = consolidation(
    storage=[{"object": "oil bottle", "preferred_location": "counter", "context": "after use", "confidence": 0.7,
              "evidence": "put back after pouring", "supporting_episodes": ["S2", "S1"]}],
    habits=[{"habit": "After pouring oil into the pan, takes the condiments", "trigger": "pour oil",
             "next_action": "take condiments", "objects_involved": ["oil", "sauce"], "confidence": 0.6,
             "supporting_episodes": "S2, S3"}],
    sequences=[{"pattern_name": "fry chicken", "goal": "fry chicken", "activity_type": "multi_step_cooking",
                "key_objects": ["chicken", "pan", "oil"], "confidence": 0.8,
                "key_steps": ["pour oil on pan", "slice chicken", "add chicken to pan", "fry chicken"],
                "supporting_episodes": ["S2", "S4"]}],
)
V104 = consolidation(
    storage=[{"object": "oil bottle", "preferred_location": "counter", "context": "after_use", "confidence": 0.6,
              "supporting_episodes": ["S12"]}],
    workflows=[{"pattern": "Pans are washed at the sink, then go on the hob", "category": "cookware",
                "use": "wash @ sink area", "then": "put on hob", "objects": ["pan"], "confidence": 0.6,
                "supporting_episodes": [2, "[S3]"]}],
)
# Findings are numbered per video in prompt order: storage, habits, workflows, sequences.
# F1 103 storage, F2 103 habit, F3 103 sequence, F4 104 storage, F5 104 workflow.
ACROSS = consolidation(
    storage=[{"object": "oil bottle", "preferred_location": "counter", "context": "after_use", "confidence": 0.8,
              "supporting_episodes": ["F1", "F4"]}],
    habits=[{"habit": "After pouring oil into the pan, takes the condiments", "trigger": "pour oil",
             "next_action": "take condiments", "objects_involved": ["oil", "sauce"], "confidence": 0.7,
             "supporting_episodes": ["F2", "F99"]},  # F99 does not exist: dropped, the habit stays
            {"habit": "Sings while cooking", "confidence": 0.9,
             "supporting_episodes": ["F42", "P09_999#t0001"]}],  # nothing real: not written
    workflows=[{"pattern": "Pans are washed at the sink, then go on the hob", "category": "cookware",
                "use": "wash @ sink area", "then": "put on hob", "objects": ["pan"], "confidence": 0.6,
                "supporting_episodes": ["F5"]}],
    sequences=[{"pattern_name": "fry chicken", "goal": "fry chicken", "activity_type": "multi_step_cooking",
                "key_objects": ["chicken", "pan", "oil"], "confidence": 0.8,
                "key_steps": ["pour oil on pan", "slice chicken", "add chicken to pan", "fry chicken"],
                "supporting_episodes": ["F3"]}],
)
SKILLS = json.dumps({"routine_skills": [
    {"goal": "cook chicken", "activity_type": "multi_step_cooking", "key_objects": ["chicken", "pan"],
     "canonical_steps": ["take chicken", "slice chicken", "add condiments to chicken", "fry chicken"],
     "supporting_evidence_ids": ["E001", "E3", "E999"], "confidence": 0.75},
]})
PREFS = json.dumps({"generated_preferences": [
    {"subtype": "tool", "preference": "Uses a knife to cut chicken", "keywords": ["Knife", "cut", "chicken"],
     "objects": ["knife", "chicken"], "context": "cutting meat", "confidence": 0.7,
     "evidence_summary": "cuts chicken with a knife", "supporting_evidence_ids": ["E002", "P09_999#t0009"]},
    {"subtype": "habit", "preference": "Always dances", "supporting_evidence_ids": ["E777", "X1"]},
]})
DROPPED_IDS = 1 + 2 + 2 + 1 + 2  # F99; F42 + P09_999; E999 (episodes and segments); P09_999; E777 + X1
SCRIPT = [V103, V104, EMPTY, EMPTY, ACROSS, SKILLS, PREFS]


def turns(*contents):
    return [Turn(content=c, usage=USAGE) for c in contents]


def processors(server, **options):
    return get_processors("llm", options={"backend": "openai", "base_url": server.base_url, "model": MODEL,
                                          "timeout_s": 10, **options})


def user_prompt(request: dict) -> str:
    return request["messages"][1]["content"]  # the repair turn appends after it


def lines(text: str, prefix: str) -> dict[str, str]:
    return {m.group(1): m.group(2) for m in re.finditer(rf"^({prefix}\d+) (.*)$", text, re.M)}


def segment_at(video: str, seconds: float) -> str:
    return f"{video}#t{int(seconds // 10):04d}"


def segment_of(video: str, line: str) -> str:
    """The segment a prompt line "S3 20-30 s @place: ..." describes."""
    return segment_at(video, float(re.match(r"([\d.]+)-", line).group(1)))


def evidence(store: Store) -> dict[str, dict]:
    return {r["id"]: r for r in store.rows("_explore_evidence", participant=P)}


def by_statement(store: Store) -> dict[str, dict]:
    rows = store.query("MATCH (p:Preference) WHERE p.participant = $p RETURN p.id AS id, p.statement AS statement, "
                       "p.subtype AS subtype, p.source AS source, p.processor AS processor, p.keywords AS keywords, "
                       "p.source_videos AS videos", {"p": P}).to_dicts()
    return {r["statement"]: r for r in rows}


def routines(store: Store) -> dict[str, dict]:
    return {(r["source"], r["goal"]): r for r in store.rows("routines", participant=P)}


def test_scripted_replies_become_routines_and_preferences_supported_by_the_cited_segments(bank, embedder):
    with ScriptedServer(turns(*SCRIPT)) as server:
        knowledge = finish_participant(bank, P, embedder, processors=processors(server))
    assert server.pending == 0 and len(server.requests) == 7
    assert all(r["model"] == MODEL and r["response_format"]["type"] == "json_schema" for r in server.requests)
    prompts = [user_prompt(r) for r in server.requests]
    for video, text in zip(VIDEOS, prompts):
        assert f"completed video {video}" in text
    s103, s104 = lines(prompts[0], "S"), lines(prompts[1], "S")
    findings = lines(prompts[4], "F")
    assert [f.split(" (")[0] for f in findings.values()] == [
        "P09_103 storage", "P09_103 habit", "P09_103 action sequence", "P09_104 storage", "P09_104 workflow"]
    episodes = lines(prompts[5], "E")
    assert prompts[5].split("\n\nTask")[0] == prompts[6].split("\n\nTask")[0], "one evidence list for both passes"

    with Store(bank.db_path(P)) as store:
        segments = {r["id"]: r for r in store.query(
            "MATCH (s:Segment) WHERE s.participant = $p RETURN s.id AS id, s.summary AS summary", {"p": P}).to_dicts()}
        prefs, rts, ev = by_statement(store), routines(store), evidence(store)
        about = store.query("MATCH (p:Preference)-[:ABOUT]->(e:Entity) WHERE p.participant = $p "
                            "RETURN p.statement AS statement, e.kind AS kind", {"p": P}).rows()
        calls = store.rows("model_calls_by_role", participant=P)

    # The handle -> segment mapping agrees with what the model was shown.
    for h in ("S1", "S2", "S3", "S4"):
        assert segments[segment_of("P09_103", s103[h])]["summary"] in s103[h]

    storage = prefs["After using the oil bottle, usually puts it on the counter"]
    habit = prefs["After pouring oil into the pan, takes the condiments"]
    workflow = prefs["Pans are washed at the sink, then go on the hob"]
    tool = prefs["Uses a knife to cut chicken"]
    task_made = {k for k, v in prefs.items() if v["source"] == "tasks"}  # task patterns: from the typed steps, any processor
    assert task_made and {prefs[k]["subtype"] for k in task_made} <= {"order", "staging", "batch", "repetition", "setup", "carrier",
                                                                                  "closure"}
    assert knowledge.task_rows and {t.video for t in knowledge.tasks} <= set(VIDEOS)
    prefs = {k: v for k, v in prefs.items() if k not in task_made}
    assert set(prefs) == {storage["statement"], habit["statement"], workflow["statement"], tool["statement"]}
    assert (storage["subtype"], habit["subtype"], workflow["subtype"], tool["subtype"]) == ("storage", "habit", "workflow", "tool")
    assert {p["processor"] for p in prefs.values()} == {"llm"}
    assert tool["source"] == "enrichment" and tool["keywords"] == ["knife", "cut", "chicken"]
    assert sorted(storage["videos"]) == ["P09_103", "P09_104"]

    def linked(row):
        return set(ev[row["id"]]["linked"])

    assert linked(storage) == {segment_of("P09_103", s103["S1"]), segment_of("P09_103", s103["S2"]),
                               segment_of("P09_104", s104["S12"])}
    assert linked(habit) == {segment_of("P09_103", s103["S2"]), segment_of("P09_103", s103["S3"])}
    assert linked(workflow) == {segment_of("P09_104", s104["S2"]), segment_of("P09_104", s104["S3"])}
    assert ("After using the oil bottle, usually puts it on the counter", "bottle") in about

    # Enrichment: the skill rests on episodes E001 and E003 (E999 is invented), the tool
    # preference on E002 (the invented segment id is dropped).
    e1, e2, e3 = (episodes[h] for h in ("E001", "E002", "E003"))
    window = re.compile(r"^(P09_\d+) ([\d.]+)-([\d.]+) s")

    def first(line):
        video, t0, _ = window.match(line).groups()
        return segment_at(video, float(t0))

    def span(line):
        video, t0, t1 = window.match(line).groups()
        return {segment_at(video, t) for t in range(int(float(t0)) // 10 * 10, int(float(t1)) + 1, 10)}

    skill = rts[("routine_skill", "cook chicken")]
    assert ev[skill["id"]]["cited"] == [first(e1), first(e3)]
    assert set(ev[skill["id"]]["linked"]) <= span(e1) | span(e3)
    assert linked(tool) and linked(tool) <= span(e2)
    seq = rts[("action_sequence", "fry chicken")]
    assert set(ev[seq["id"]]["linked"]) == {segment_of("P09_103", s103["S2"]), segment_of("P09_103", s103["S4"])}
    assert {k for k in rts if k[0] != "task_routine"} == {("routine_skill", "cook chicken"), ("action_sequence", "fry chicken")}

    for row in ev.values():  # nothing invented reached the graph
        assert row["cited"] and set(row["cited"]) <= set(row["linked"]) <= set(segments)
    assert "Sings while cooking" not in prefs and "Always dances" not in prefs
    assert knowledge.dropped_ids == DROPPED_IDS and knowledge.dropped_records == 2
    assert not knowledge.failed_steps and len(knowledge.steps) == 7

    assert {(c["role"], c["calls"], c["failed"], c["tokens_in"]) for c in calls} == {
        ("consolidation", 5, 0, 5 * 1500), ("enrichment", 2, 0, 2 * 1500)}
    entry = bank.manifest()["participants"][P]
    n_task_routines = sum(x.family == "canonical" for x in knowledge.patterns)
    assert entry["inferred"]["processor"] == "llm" and entry["counts"]["routines"] == 2 + n_task_routines
    assert entry["counts"]["preferences"] == 4 + len(task_made) and entry["inferred"]["dropped_ids"] == DROPPED_IDS


def test_a_malformed_reply_is_repaired_once_then_recorded_as_a_failed_call_with_nothing_half_written(bank, embedder, caplog):
    bad_skills = json.dumps({"routine_skills": [{"goal": "fry", "supporting_evidence_ids": ["E001"]}]})  # no steps
    prefs = json.dumps({"generated_preferences": [
        {"subtype": "tool", "preference": "Uses a knife to cut chicken", "supporting_evidence_ids": ["E002"]}]})
    across = consolidation(sequences=[{"goal": "fry chicken", "key_steps": ["pour oil", "fry chicken"],
                                       "supporting_episodes": ["F3"]}])
    script = turns("{not json", V103,  # repaired
                   "Sure! The video shows a lot of cooking.", '{"storage_preferences": []}',  # stays invalid
                   EMPTY, EMPTY, across, bad_skills, bad_skills, prefs)
    with caplog.at_level(logging.WARNING, logger="memora_graph.consolidate.llm"):
        with ScriptedServer(script) as server:
            knowledge = finish_participant(bank, P, embedder, processors=processors(server))
    assert server.pending == 0
    repair = server.requests[1]["messages"]
    assert repair[-2] == {"role": "assistant", "content": "{not json"} and "could not be used" in repair[-1]["content"]
    findings = lines(user_prompt(server.requests[6]), "F")
    assert findings and not any(f.startswith("P09_104") for f in findings.values()), "no findings of the failed video"
    assert [s.step for s in knowledge.failed_steps] == ["video P09_104", "routine skills"]
    assert any("P09_104" in r.getMessage() and "adds no records" in r.getMessage() for r in caplog.records)

    with Store(bank.db_path(P)) as store:
        failed = store.rows("model_calls_failed", participant=P)
        by_role = {r["role"]: r for r in store.rows("model_calls_by_role", participant=P)}
        ev = evidence(store)
        rts, prefs = routines(store), by_statement(store)
    assert [(f["role"], f["video"], f["repairs"]) for f in sorted(failed, key=lambda f: f["role"])] == [
        ("consolidation", "P09_104", 1), ("enrichment", "", 1)]
    assert all("after one repair turn" in f["error"] for f in failed)
    assert (by_role["consolidation"]["calls"], by_role["consolidation"]["failed"], by_role["consolidation"]["repairs"]) == (5, 1, 2)
    assert (by_role["enrichment"]["calls"], by_role["enrichment"]["failed"], by_role["enrichment"]["repairs"]) == (2, 1, 1)
    assert {k for k in rts if k[0] != "task_routine"} == {("action_sequence", "fry chicken")}, \
        "no routine skill from the failed step"
    assert {k for k, v in prefs.items() if v["source"] != "tasks"} == {"Uses a knife to cut chicken"}
    task_ids = {v["id"] for v in prefs.values() if v["source"] == "tasks"} | \
        {r["id"] for k, r in rts.items() if k[0] == "task_routine"}  # from the typed steps of every video
    assert not any(s.startswith("P09_104") for i, row in ev.items() if i not in task_ids for s in row["linked"])
    assert bank.manifest()["participants"][P]["inferred"]["failed_steps"][0].startswith("video P09_104: ")


def test_when_every_step_fails_the_previous_knowledge_stays_and_the_calls_are_recorded(bank, embedder):
    with Store(bank.db_path(P)) as store:
        before = evidence(store)
    manifest_before = bank.manifest()["participants"][P]
    with ScriptedServer(turns(*["not json"] * 12)) as server:  # 4 videos + skills + preferences, each repaired once
        with pytest.raises(ConsolidationError, match="every model step failed"):
            finish_participant(bank, P, embedder, processors=processors(server))
    assert server.pending == 0
    with Store(bank.db_path(P)) as store:
        assert evidence(store) == before and before
        failed = store.rows("model_calls_failed", participant=P)
    assert sorted(f["role"] for f in failed) == ["consolidation"] * 4 + ["enrichment"] * 2
    after = bank.manifest()["participants"][P]
    # the knowledge is as it was; the integrity record follows the file (the failed calls were written)
    assert {k: v for k, v in after.items() if k != "integrity"} == {k: v for k, v in manifest_before.items() if k != "integrity"}
    assert after["integrity"]["tables"]["ModelCall"] == manifest_before["integrity"]["tables"]["ModelCall"] + 6
    bank.open(P).close()  # and the bank still opens: the record matches the file


def test_a_server_error_stops_the_participant_before_anything_is_written(bank, embedder):
    with Store(bank.db_path(P)) as store:
        before = evidence(store)
    with ScriptedServer([Turn(status=400, error="context length exceeded")]) as server:
        with pytest.raises(ModelServerError, match="context length exceeded"):
            finish_participant(bank, P, embedder, processors=processors(server))
    with Store(bank.db_path(P)) as store:
        assert evidence(store) == before
        failed = store.rows("model_calls_failed", participant=P)
    assert [(f["role"], f["video"]) for f in failed] == [("consolidation", "P09_103")]


def test_prompts_are_bounded_and_handles_resolve_loosely(small_bank):
    path, _ = small_bank
    with Bank(path).open("P37") as store:
        memory = load_memory(store, "P37")
    limits = PromptLimits(segments_per_video=10, objects_per_video=5, episodes=7, line_chars=90)
    procs = get_processors("llm", options={"backend": "openai", "model": "m", "limits": limits})
    text, handles = procs.consolidation.video_prompt(memory, "P37_101")
    shown = lines(text, "S")
    assert len(shown) == len(handles) == 10 and "10 segments shown, evenly spaced" in text
    assert all(len(f"{h} {line}") <= 90 for h, line in shown.items())
    assert text.count("\n- ") == 5
    times = [float(line.split("-")[0]) for line in shown.values()]
    assert times == sorted(times) and times[-1] > 1000, "evenly spaced over the whole video"
    evidence_text, eh = procs.enrichment.evidence(memory, get_processors().consolidation.consolidate_participant(memory, []))
    assert len(lines(evidence_text, "E")) == len(eh) == 7

    h = Handles("S")
    a, b = h.add("seg-a"), h.add("seg-b")
    assert (a, b) == ("S1", "S2")
    assert [h.get(r) for r in ("S1", "s2", "[S2]", "2", "S002", "F1", "S3", "P09_103#t0001")] == [
        "seg-a", "seg-b", "seg-b", "seg-b", "seg-b", None, None, None]
    item = StorageItem.model_validate({"object": "mug", "preferred_location": "shelf", "confidence": "85%",
                                       "supporting_episodes": ["S1, S2", 3]})
    assert item.confidence == 0.85 and item.supporting_episodes == ["S1", "S2", "3"]


def test_processor_options(tmp_path):
    with pytest.raises(MemoraError, match="does not take these options"):
        get_processors("deterministic", options={"model": "m"})
    with pytest.raises(ModelUnavailableError) as err:
        get_processors("llm", options={"backend": "offline"})
    assert str(err.value) == OFFLINE_MESSAGE and "memora consolidate BANK --processor llm --backend openai" in OFFLINE_MESSAGE
    with pytest.raises(MemoraError, match="unknown option"):
        get_processors("llm", options={"backend": "openai", "temprature": 0})


def test_cli_consolidate_end_to_end_with_stats_and_errors(bank, small_bank):
    runner = CliRunner()
    path = str(bank.path)
    deterministic = Bank(small_bank[0]).manifest()["participants"][P]["counts"]
    with ScriptedServer(turns(*SCRIPT), models=(MODEL, "other")) as server:
        result = runner.invoke(main, ["consolidate", path, "--participants", P, "--processor", "llm", "--backend",
                                      "openai", "--base-url", server.base_url, "--model", MODEL, "--quiet", "--json",
                                      "--concurrency", "1"])  # the script answers in order
    assert result.exit_code == 0, result.output
    assert server.pending == 0
    row = json.loads(result.output)[0]
    with Bank(path).open(P) as store:  # the task memory's records come from the typed steps, whatever the processor
        task_r = sum(r["source"] in TASK_SOURCES for r in store.rows("baseline_routines", participant=P))
        task_p = sum(r["source"] in TASK_SOURCES for r in store.rows("baseline_preferences", participant=P))
    assert (row["participant"], row["processor"], row["routines"] - task_r, row["preferences"] - task_p) == (P, "llm", 2, 4)
    assert (row["dropped_ids"], row["dropped_records"], row["model_calls"], row["failed_steps"]) == (DROPPED_IDS, 2, 7, 0)

    roles = runner.invoke(main, ["stats", path, "--participant", P, "--calls", "role", "--json"])
    assert roles.exit_code == 0, roles.output
    assert {r["role"]: r["calls"] for r in json.loads(roles.output)} == {"consolidation": 5, "enrichment": 2}
    table = runner.invoke(main, ["stats", path, "--calls", "role"])
    assert "consolidation" in table.output and "enrichment" in table.output
    data = Bank(path).manifest()
    assert data["participants"][P]["inferred"]["processor"] == "llm" and data["condition"] == "memora_full"

    again = runner.invoke(main, ["consolidate", path, "--participants", P])  # back to the rules
    assert again.exit_code == 0, again.output
    assert "deterministic" in again.output
    counts = Bank(path).manifest()["participants"][P]["counts"]
    assert (counts["routines"], counts["preferences"]) == (deterministic["routines"], deterministic["preferences"])
    assert call_stats(path, [P])["calls"].to_list() == [5, 2], "the calls of earlier runs stay on record"


def test_cli_consolidate_says_plainly_what_is_wrong(bank):
    runner = CliRunner()
    path = str(bank.path)
    wrong = runner.invoke(main, ["consolidate", path, "--processor", "gpt"])
    assert wrong.exit_code == 2 and "no consolidation processor 'gpt'" in wrong.output
    assert "registered: deterministic, llm" in wrong.output
    offline = runner.invoke(main, ["consolidate", path, "--processor", "llm", "--backend", "offline"])
    assert offline.exit_code == 2 and "LLM consolidation needs a model server" in offline.output
    assert "memora consolidate BANK --processor llm --backend openai --base-url" in offline.output
    stray = runner.invoke(main, ["consolidate", path, "--model", "m"])
    assert stray.exit_code == 2 and "only apply with --processor llm" in stray.output
    nobody = runner.invoke(main, ["consolidate", path, "--participants", "P01"])
    assert nobody.exit_code == 1 and "no participant P01" in nobody.output and "P09, P37" in nobody.output
    with ScriptedServer([]) as server:
        down = server.base_url
    refused = runner.invoke(main, ["consolidate", path, "--processor", "llm", "--base-url", down, "--quiet"])
    assert refused.exit_code == 1 and "connection refused" in refused.output

    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from memora_graph.store import Store; s = Store(sys.argv[1], read_only=False); "
        "print('ready', flush=True); time.sleep(30)"), str(bank.db_path(P))], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "ready"
        with ScriptedServer([]) as server:
            locked = runner.invoke(main, ["consolidate", path, "--participants", P, "--processor", "llm",
                                          "--base-url", server.base_url, "--quiet"])
        assert locked.exit_code == 1 and "cannot consolidate P09" in locked.output
        assert "locked by another process" in locked.output
        assert server.requests == [], "no model call before the lock is known"
    finally:
        holder.kill()
        holder.wait()


def test_cli_consolidate_passes_backend_options(bank):
    """-o NAME VALUE reaches the backend: llama-cpp-python's server needs structured_output json_object."""
    runner = CliRunner()
    path = str(bank.path)
    with ScriptedServer(turns(*SCRIPT), models=(MODEL,)) as server:
        result = runner.invoke(main, ["consolidate", path, "--participants", P, "--processor", "llm", "--base-url",
                                      server.base_url, "-o", "structured_output", "json_object", "-o", "max_tokens",
                                      "512", "--concurrency", "1", "--quiet"])
    assert result.exit_code == 0, result.output
    assert len(server.requests) == len(SCRIPT)
    for request in server.requests:
        assert request["response_format"]["type"] == "json_object" and request["response_format"]["schema"]["properties"]
        assert request["max_tokens"] == 512
    stray = runner.invoke(main, ["consolidate", path, "-o", "max_tokens", "512"])
    assert stray.exit_code == 2 and "-o only apply with --processor llm" in stray.output
    clash = runner.invoke(main, ["consolidate", path, "--processor", "llm", "-o", "model", "m"])
    assert clash.exit_code == 2 and "-o model: use the command's own option" in clash.output
    with ScriptedServer([]) as server:
        unknown = runner.invoke(main, ["consolidate", path, "--processor", "llm", "--base-url", server.base_url,
                                       "-o", "max_tokenz", "5", "--quiet"])
    assert unknown.exit_code == 1 and "'max_tokenz': unknown option" in unknown.output


def test_per_video_calls_in_flight_together_write_what_one_at_a_time_writes(small_bank, tmp_path, embedder):
    """concurrency=4: the four per-video calls are at the server together; the records, their
    evidence and the ModelCall rows (in order) are those of a one-at-a-time run."""
    def respond(body):
        prompt = user_prompt(body)
        name = body["response_format"]["json_schema"]["name"]
        if name == "ConsolidationReply":
            for video, reply in (("P09_103", V103), ("P09_104", V104)):
                if f"completed video {video}" in prompt:
                    return Turn(content=reply, usage=USAGE, delay_s=0.5 if video == "P09_103" else 0.2)
            across = "F1" in prompt and "completed video" not in prompt
            return Turn(content=ACROSS if across else EMPTY, usage=USAGE, delay_s=0 if across else 0.2)
        return Turn(content=SKILLS if name == "SkillsReply" else PREFS, usage=USAGE)

    results = {}
    for c in (1, 4):
        src, _ = small_bank
        copy = tmp_path / f"bank{c}"
        shutil.copytree(src, copy, ignore=shutil.ignore_patterns(".staging"))
        with ScriptedServer(responder=respond) as server:
            finish_participant(Bank(copy), P, embedder, processors=processors(server, concurrency=c))
            stats = server.stats()
        with Store(Bank(copy).db_path(P)) as store:
            calls = store.query("MATCH (c:ModelCall) WHERE c.participant = $p RETURN c.id AS id, c.video AS video, "
                                "c.role AS role, c.prompt_hash AS h ORDER BY c.id", {"p": P}).rows()
            results[c] = (by_statement(store), routines(store), evidence(store), [row[1:] for row in calls], stats)
    assert results[1][4]["inflight_max"] == 1 and results[4][4]["inflight_max"] >= 2
    assert results[1][0] and results[1][1]  # something was written
    for part in range(4):
        assert results[1][part] == results[4][part]
