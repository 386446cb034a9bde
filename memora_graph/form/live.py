"""Live memory: write experience into a participant's memory as it happens, one moment at a time.

    from memora_graph.form.live import LiveWriter, Moment
    with LiveWriter("banks/home", "P01") as memory:
        done = memory.remember(Moment(video="kitchen-1", start=12.5, end=14.0, text="put the kettle on the counter"))
        done.ops                               # the editor's ADD / UPDATE / DELETE / NOOP, with entity ids

Each `remember` perceives the narration (offline, deterministic: perceive/narrations.py reads the
words into EPIC classes, `perceive_moment` makes the layered record), embeds it with the bank's
model, runs the online editor (form/editor.py) against the registry held in memory, and commits
everything the moment adds (segment, state events, editor operations, entity and place changes)
in one Kùzu transaction, with a `Remembered` row under the client's key: a retried call (same
video and start, or the same explicit id) returns its first answer and writes nothing. Once
`remember` returns, the write is committed to Kùzu's write-ahead log: a killed process loses none
of it, and the next writer replays it and records the database's integrity again. The writer
checkpoints the log into the database file on a schedule bounded by bytes, moments and seconds
(form/checkpoint.py, `CheckpointPolicy`), so a restart replays little.

One writer per participant database: the writer holds the participant's build lock and its
write mark (op "live") for as long as it is open; a second writer, a build, or a reader in
another process is told the memory is busy. Readers in the writer's own process use its store
(`memora serve --writable` does).
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import polars as pl

from memora_graph import schema
from memora_graph.bank import Bank, pid_alive
from memora_graph.embed import torch_threads
from memora_graph.errors import BankError, DataError, StoreError
from memora_graph.form import intake
from memora_graph.form.build import entity_row, place_row
from memora_graph.form.checkpoint import CheckpointPolicy, Checkpointer
from memora_graph.form.editor import EntityEditor, get_editor_policy, identity_text
from memora_graph.form.environment import PlaceMemory, PlaceState, place_id
from memora_graph.form.live_journal import Journal
from memora_graph.files import side_files
from memora_graph.perceive.narration import MomentContext, perceive_moment
from memora_graph.perceive.narrations import NarrationReader, check_moment
from memora_graph.records import LayeredSegment
from memora_graph.store import Store

OP = "live"  # the write mark a live writer holds (BANK/manifest.json "writing")
log = logging.getLogger("memora_graph.integrity")


_OPEN: set[tuple[str, str]] = set()  # (bank, participant) of the writers open in this process
_OPEN_LOCK = threading.Lock()


LIVE_ENCODERS = ("onnx", "torch")
# the columns of a StateEvent row the live writer writes (queries/_live_add_event.cypher)
_EVENT = ("id", "entity", "video", "turn", "t", "ord", "state", "location", "prev_state", "prev_location", "zone",
          "held_by", "relative_to", "relation", "action", "narration", "op")
_SCALAR_ROWS = 3  # up to this many changed entities, events or operations: one statement each, else one UNWIND
# the Entity columns an edit changes (what queries/_live_entity_update.cypher sets)
_ENTITY_UPDATE = ("id", "status", "merged_into", "state", "location", "held_by", "color", "material", "size",
                  "last_seen", "last_video", "last_turn", "n_observations")


class _OnnxPassages:
    """A remember's passages (the segment's summary, new identity and place texts) through the
    ONNX Runtime fp32 export of the bank's MiniLM (memora_graph/onnx_embed.py), one text at a
    time: ~6 ms of CPU where the PyTorch model takes ~20 (sentence-transformers' per-call work
    dominates a single short text). Its vectors match the PyTorch model's to cosine >= 0.9999999
    on P01's narrations (each component within 2.2e-7; PyTorch one text at a time, as remembers
    ran before, is within 1.1e-7 of a build's batches), and no top-10 list changed when a
    vector is swapped for it (docs/findings/live-remember-latency.md, "Where a remember's CPU goes")."""

    def __init__(self, model: str):
        from memora_graph.onnx_embed import OnnxEmbedder

        self._onnx = OnnxEmbedder(variant="fp32", threads=1)
        self.name, self.dim = model, self._onnx.dim

    def uses_torch(self, kind: str) -> bool:
        return False

    def encode(self, texts: list[str], kind: str = "passage") -> np.ndarray:
        return self._onnx.encode(texts, kind=kind)


def live_embedder(model: str):
    """The embedder of a live writer: for the bundled MiniLM, its ONNX fp32 export (see
    `_OnnxPassages`), unless MEMORA_LIVE_ENCODER=torch; another model: its PyTorch model. An
    export that cannot be made falls back to PyTorch (logged)."""
    from memora_graph.embed import DEFAULT_MODEL, CachedEmbedder, get_embedder

    choice = (os.environ.get("MEMORA_LIVE_ENCODER") or "onnx").strip().lower()
    if choice not in LIVE_ENCODERS:
        raise BankError(f"unknown live encoder {choice!r} (MEMORA_LIVE_ENCODER); choose one of: "
                        + ", ".join(LIVE_ENCODERS))
    if choice == "torch" or model != DEFAULT_MODEL:
        return get_embedder(model)
    try:
        return CachedEmbedder(_OnnxPassages(model))
    except Exception as exc:  # noqa: BLE001 - no ONNX Runtime or no export: the PyTorch model embeds
        logging.getLogger("memora_graph.embed").warning(f"live memory embeds with PyTorch: the ONNX export of "
                                                        f"{model} is not available ({exc})")
        return get_embedder(model)


class WriterBusy(BankError):
    """Another writer (a live writer, a build, a reader holding the file) has the participant."""


@dataclass
class Moment:
    """One narrated moment: what happened (`text`), in which video, when (seconds). `key`:
    the client's idempotency key (default: the video and the start time)."""

    video: str
    start: float
    end: float
    text: str
    key: str | None = None

    def client_key(self) -> str:
        return self.key or f"{self.video}@{self.start:.3f}"


@dataclass
class Remembered:
    """A remember's answer: the segment written and the editor's operations with their ids."""

    key: str
    participant: str
    segment: str
    video: str
    turn: int
    ops: list[dict]
    duplicate: bool = False  # the key was acknowledged before: nothing was written now
    unknown_words: list[str] = field(default_factory=list)
    note: str = ""  # said when the moment was kept as text alone (no word any class covers)
    seconds: float = 0.0
    delta: dict = field(default_factory=dict, repr=False)  # what changed, for readers' caches

    def as_dict(self) -> dict:
        return {"key": self.key, "participant": self.participant, "segment": self.segment, "video": self.video,
                "turn": self.turn, "ops": self.ops, "duplicate": self.duplicate, "unknown_words": self.unknown_words,
                **({"note": self.note} if self.note else {})}


@dataclass
class _Video:
    turns: int = 0  # segments written (the next turn id)
    duration: float = 0.0
    actions: int = 0
    last_segment: str | None = None
    ctx: MomentContext = field(default_factory=MomentContext)


def _shallow(e):
    """A shallow copy of an entity record (what `copy.copy` makes of a dataclass, ~2.5x faster: at
    1,000 h a remember snapshots ~50 entities of the observed kinds)."""
    other = object.__new__(type(e))
    other.__dict__.update(e.__dict__)
    return other


def _floats(vec) -> list[float]:
    return np.asarray(vec, dtype=np.float32).tolist()


def _now() -> datetime:
    return datetime.now(timezone.utc).replace(tzinfo=None)


def recover(bank: Bank, participant: str) -> bool:
    """After a live writer (or any non-build write) died without closing: replay its write-ahead
    log (what it acknowledged) into the database, and record the database's integrity and
    counts again. A log is first opened in a child process (a crash there is an error here).
    Returns whether anything was recovered."""
    data = bank.manifest()
    mark = data.get("writing", {}).get(participant)
    if not mark or mark.get("pid") == os.getpid():
        return False
    if pid_alive(mark.get("pid")):
        raise WriterBusy(bank.interrupted_message(participant, mark))
    if mark.get("op") == "build":
        raise BankError(bank.interrupted_message(participant, mark))
    db = bank.db_path(participant)
    t0 = time.perf_counter()
    if participant not in data["participants"]:  # killed while creating the participant: nothing acknowledged
        for f in [db, *side_files(db)]:
            f.unlink(missing_ok=True)
        bank.update_manifest(lambda d: (d.get("writing", {}).pop(participant, None),
                                        d.pop("writing", None) if not d.get("writing") else None))
        return True
    replayed = None
    if side_files(db):  # a copy of the log first; then replayed into the file in a child process (a crash
        from memora_graph.files import keep_log, replay  # there is an error here), its pool sized from the log

        kept = keep_log(db)
        try:
            replayed = replay(db, participant)["replay"]
        except BankError as exc:  # a log Kùzu refuses: the intake journal re-applies what it held, if kept
            if mark.get("op") != OP or not (kept := intake.recover_without_log(bank.path, participant, db, exc)):
                raise
    bank.mark_writing(participant, mark.get("op") or OP)
    with Store(db, read_only=False) as store:  # (a log left now is replayed here; the close checkpoints it)
        videos = [r["video"] for r in store.rows("_live_videos", participant=participant)]
    _record_videos(bank, participant, videos)
    bank.record_integrity(participant)
    what = f" ({replayed['log_bytes'] / 1e6:.1f} MB, replayed in {replayed['seconds_with_checkpoint']:.1f} s; a " \
           f"copy is in {kept})" if replayed else ""
    log.warning(f"{db}: recovered the writes of process {mark.get('pid')} ({mark.get('op')}, since "
                f"{mark.get('since', '?')}) from its write-ahead log{what}; in {time.perf_counter() - t0:.1f} s")
    return True


def _record_videos(bank: Bank, participant: str, videos: list[str]) -> None:
    def change(data: dict) -> None:
        entry = data["participants"].get(participant)
        if entry is not None:
            entry["videos"] = sorted(set(videos))

    bank.update_manifest(change)


class LiveWriter:
    """A participant's memory held open for writing, one moment at a time (see the module)."""

    def __init__(self, bank: str | Path, participant: str, embedder=None, reader: NarrationReader | None = None,
                 lock_wait_s: float = 0.5, store_lock=None, on_commit=None, checkpoint: CheckpointPolicy | None = None,
                 readers_apart: bool = False):
        """`store_lock`: taken around every use of the store (the readers of a server share it,
        so perception, embedding and the editor's decision run outside it); `on_commit(delta)`
        runs inside it right after each commit (a server updates its readers' caches there).
        `checkpoint`: when the write-ahead log is checkpointed (default `CheckpointPolicy()`:
        4 MB, 1,000 moments or 60 s, whichever comes first; form/checkpoint.py).
        `readers_apart`: the readers read through connections of their own (`Store.reader`, the
        last committed snapshot), never through `store`: the transaction (and a checkpoint) then
        runs outside `store_lock`, which is taken only around `on_commit`, so a reader waits for
        the readers' caches to take a moment in (a millisecond or so), not for Kùzu to commit it.
        Whoever else writes through `store` then holds this writer's `lock` (`write_lock`)."""
        self.bank = Bank(bank)
        self._store_lock = store_lock if store_lock is not None else threading.RLock()
        # what guards the writer's own connection: the readers' lock, unless they read apart
        self._conn_lock = threading.RLock() if readers_apart else self._store_lock
        self._on_commit = on_commit
        self.participant = participant
        self.bank.db_path(participant)  # a malformed id fails here
        self._stack = ExitStack()
        self._lock = threading.RLock()  # one remember at a time; readers of `store` take it too
        self.store: Store | None = None
        self.checkpoint_policy = checkpoint or CheckpointPolicy()
        try:
            self._open(embedder, reader, lock_wait_s)
        except BaseException:
            self._stack.close()
            raise

    # -- opening -----------------------------------------------------------------------
    def _open(self, embedder, reader, lock_wait_s: float) -> None:
        from memora_graph.embed import DEFAULT_MODEL

        p = self.participant
        mine = (str(self.bank.path.resolve()), p)
        with _OPEN_LOCK:  # POSIX locks are the process's: a second writer here must be refused by hand
            if mine in _OPEN:  # (two read-write Kùzu databases on one file in one process corrupt it)
                raise WriterBusy(self._busy_message("a writer of this process has it open"))
            _OPEN.add(mine)
        self._stack.callback(lambda: _OPEN.discard(mine))
        try:
            self._stack.enter_context(self.bank.participant_lock(p, wait_s=lock_wait_s))
        except BankError:
            raise WriterBusy(self._busy_message()) from None
        if self.bank.exists():
            data = self.bank.manifest()
            self.embedder = embedder or live_embedder(data["embed_model"])
            if data.get("mode") != "edited":
                raise BankError(f"{self.bank.path}: a '{data.get('mode')}' bank; live memory writes edited banks only")
            recover(self.bank, p)
        else:
            self.embedder = embedder or live_embedder(os.environ.get("MEMORA_EMBED_MODEL", DEFAULT_MODEL))
            self.bank.init(mode="edited", embed_model=self.embedder.name, consolidated=False)
        if p not in self.bank.manifest()["participants"]:
            self._create()
        for attempt in range(2):
            # the database as this writer finds it, checked against its integrity record (None under
            # --no-verify): what the persisted tool stores a server reads must have been computed from
            opened = self.bank.checked_sha256(p)
            try:
                self.store = self.bank.open(p, read_only=False, op=OP, auto_checkpoint=False)  # our schedule
            except StoreError as exc:
                if "lock" in str(exc).lower():
                    raise WriterBusy(self._busy_message(str(exc))) from None
                raise
            try:
                migrated = not attempt and self.store.apply_schema()
            except BaseException:
                self.store.close()
                raise
            if not migrated:
                break
            # a bank from before live memory got the Remembered table: closing records the migrated
            # database's integrity, and the writer opens that (so the stores can be tied to it)
            store, self.store = self.store, None
            store.close()
        self.intake = intake.Journal(self.bank.path, p)  # every acknowledged moment's input (form/intake.py)
        self._stack.callback(self.intake.close)
        self.journal = Journal(self.bank, p, opened)  # what the persisted tool stores lack from here on
        self._stack.callback(self._close_store)
        self.checkpointer = Checkpointer(self.checkpoint_policy, lambda: self.store, self._lock, self._conn_lock,
                                         after=self.intake.clear)
        self._stack.callback(self.checkpointer.stop)  # (before the store closes, which checkpoints)
        self.opened_sha256: str | None = opened
        self.commits = 0  # moments committed by this writer (a reader opened after one must not use stores)
        self._load()
        self.reader = reader or NarrationReader()
        self.since_consolidation = 0  # segments written since the last (incremental) consolidation
        intake.reapply(self, Moment)  # moments acknowledged that the database lacks (its log was set aside)

    def _busy_message(self, why: str = "") -> str:
        mark = (self.bank.manifest().get("writing", {}) if self.bank.exists() else {}).get(self.participant)
        who = f" by process {mark.get('pid')} ({mark.get('op')} since {mark.get('since', '?')})" if mark else ""
        return (f"{self.bank.db_path(self.participant)}: busy: {self.participant}'s memory is held{who or ' by another process'}"
                f"; one writer per participant. Send the remembers to that process (e.g. the MCP `remember` tool of "
                f"its `memora serve --writable`), or stop it and retry." + (f" ({why})" if why else ""))

    def _create(self) -> None:
        """A new participant: an empty database with the schema, recorded in the manifest."""
        p = self.participant
        db = self.bank.db_path(p)
        if db.exists():
            raise BankError(self.bank.not_listed(p, self.bank.manifest()))
        self.bank.mark_writing(p, OP)
        try:
            with Store(db, read_only=False) as store:
                store.apply_schema()
                store.copy("Participant", pl.DataFrame({"id": [p], "participant": [p]}))
            self.bank.record_participant(p, [], {})
            self.bank.record_integrity(p)
        except BaseException:
            self.bank.abandon_writing(p)
            raise

    def _load(self) -> None:
        """The editor's registry, the places and each video's end, from the database."""
        from memora_graph.form.build import load_entities

        p, s = self.participant, self.store
        entities = load_entities(s, p)
        places = [PlaceState(**{k: r["place"][k] for k in schema.columns("Place", emb=False)})
                  for r in s.fetch("_registry_places", participant=p)]
        next_ord = int(s.run("_max_state_ord", participant=p)["max_ord"][0] or 0)
        self._op_seq = int(s.run("_edit_op_count", participant=p)["n"][0] or 0)
        self.mode = self.bank.manifest().get("mode", "edited")
        self.editor = EntityEditor(p, get_editor_policy(self.mode), embed=self._embed_one, entities=entities,
                                   next_ord=next_ord)
        self.places = PlaceMemory(p, places)
        # the client keys acknowledged so far (only this writer adds any while it is open)
        self._keys: set[str] = {r["id"] for r in s.fetch("_live_remembered_keys", participant=p)}
        self._place_vecs: set[str] = set()  # places whose stored vector this writer wrote for their current text
        self.videos: dict[str, _Video] = {}
        for r in s.rows("_live_videos", participant=p):
            last = None if r["last_turn"] is None else int(r["last_turn"])
            self.videos[r["video"]] = _Video(turns=(last + 1) if last is not None else 0,
                                             duration=float(r["duration"] or 0.0), actions=int(r["n_actions"] or 0),
                                             last_segment=None if last is None else f"{r['video']}#t{last:04d}")

    def _embed_one(self, text: str) -> np.ndarray:
        return self.embedder.encode([text])[0]

    # -- closing -----------------------------------------------------------------------
    @property
    def write_lock(self):
        """Held by a remember from start to answer: whoever else writes through `store` (a
        background consolidation) holds it around its write."""
        return self._lock

    def _close_store(self) -> None:
        if self.store is not None:
            store, self.store = self.store, None
            videos = sorted(self.videos)
            store.close()  # checkpoints; records the integrity (Bank.open's on_close)
            self.intake.clear()
            _record_videos(self.bank, self.participant, videos)
            self.journal.close()  # leads the stores' database to the one just recorded

    def close(self) -> None:
        with self._lock:
            self._stack.close()

    def checkpoint(self) -> bool:
        """Checkpoint the write-ahead log into the database file now (between remembers);
        whether it succeeded (a failure is logged; the log keeps every commit)."""
        with self._lock:
            return self.store is not None and self.checkpointer.run("asked")

    def __enter__(self) -> LiveWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- remembering -------------------------------------------------------------------
    def moment(self, video: object, start: object, end: object, text: object, key: object = None,
               where: str = "remember") -> Moment:
        """A Moment from loose values, checked (a DataError names the field)."""
        video, start, end, text = check_moment(where, video, start, end, text)
        if key is not None and (not isinstance(key, str) or not key.strip() or len(key) > 200):
            raise DataError(f"{where}, field 'id': expected a non-empty key of at most 200 characters (got {key!r})")
        return Moment(video, start, end, text, key)

    def remember(self, moment: Moment) -> Remembered:
        """Perceive, embed, edit and commit one narrated moment; its answer (see `Remembered`)."""
        reading = self.reader.read(moment.text)
        action = self.reader.action(reading, self.participant, moment.video, moment.start, moment.end,
                                    narration_id=moment.client_key())
        note = (f"no word of this moment is one memory knows ({', '.join(reading.unknown)}): it is remembered as its "
                "text, with no new object or place" if reading.text_only and reading.unknown else "")
        return self._commit(moment.client_key(), moment.video, action=action, unknown=reading.unknown, note=note,
                            given={"moment": {"video": moment.video, "start": moment.start, "end": moment.end,
                                               "text": moment.text}})

    def remember_segment(self, segment: LayeredSegment | dict, key: str | None = None) -> Remembered:
        """Commit a segment record perceived elsewhere (the project's LayeredSegment schema, e.g.
        from a VLM): no perception here; the turn id is the video's next."""
        seg = segment if isinstance(segment, LayeredSegment) else LayeredSegment.model_validate(segment)
        if seg.participant_id != self.participant:
            raise DataError(f"remember: the record is {seg.participant_id}'s, this writer writes {self.participant}'s")
        return self._commit(key or f"{seg.video_id}@{seg.t_start:.3f}", seg.video_id, segment=seg,
                            given={"segment": seg.model_dump(mode="json")})

    def _commit(self, key: str, video: str, action: dict | None = None, segment: LayeredSegment | None = None,
                unknown: list[str] | None = None, note: str = "", given: dict | None = None) -> Remembered:
        t0 = time.perf_counter()
        with self._lock:
            if self.store is None:
                raise BankError(f"{self.bank.path}: this writer of {self.participant} is closed")
            p = self.participant
            done = None
            if key in self._keys:  # a retry: its first answer, from the database
                with self._conn_lock:
                    done = self.store.fetch("_live_remembered", participant=p, id=key)
            if done:
                answer = json.loads(done[0]["result"])
                return Remembered(**{**answer, "duplicate": True}, seconds=time.perf_counter() - t0)
            v = self.videos.get(video) or _Video()
            turn = v.turns
            if segment is None:
                segment = perceive_moment(p, video, turn, action, v.ctx, self.reader.classes)
            else:
                segment = segment.model_copy(update={"turn_id": turn})
            # state the writer changes only once the transaction committed: on failure it is rebuilt.
            # An edit changes active entities of the observed kinds only (an edit on any other id is
            # repaired into an ADD): those are copied, not the registry, which grows with the hours.
            touchable = self.editor.active_of_kinds({o.kind for o in segment.objects})
            snapshot = self._snapshot(touchable)
            self.intake.append(key, given or {})  # durable before the transaction (form/intake.py)
            try:
                # one short text at a time: torch's thread pool only spins against the readers' threads
                with torch_threads(1, self.embedder, kind="passage"):
                    result, rows = self._write(key, segment, v, turn, touchable)
            except BaseException:
                self._restore(snapshot)
                self.intake.cancel(key)
                raise
            self.checkpointer.committed()  # wakes the checkpoint thread if a bound is reached
            n_actions = len(segment.activity.action_breakdown)
            v.turns, v.last_segment = turn + 1, segment.segment_id
            v.duration, v.actions = max(v.duration, segment.t_end), v.actions + n_actions
            self.videos[video] = v
            self.since_consolidation += 1
            answer = Remembered(key=key, participant=p, segment=segment.segment_id, video=video, turn=turn,
                                ops=result, unknown_words=list(unknown or []), note=note, delta=rows)
            answer.seconds = time.perf_counter() - t0
            return answer

    def _snapshot(self, touchable: list):
        """What an edit changes in the writer's memory (the entities it may touch, the places,
        the counters), to put back if the transaction fails: the registry then matches the
        database again. New entities are the registry's last keys (a dict keeps its order)."""
        # a place's fields are strings, numbers and lists of strings: copying its lists is a deep copy
        # (copy.deepcopy walked every string of every place: about 0.5 ms per remember)
        places = {k: replace(pp, zones=list(pp.zones), features=list(pp.features))
                  for k, pp in self.places.places.items()}
        return ({e.id: _shallow(e) for e in touchable}, len(self.editor.entities),
                places, self.editor._ord, self._op_seq)

    def _restore(self, snap) -> None:
        touched, n, places, ord_, op_seq = snap
        for i in list(self.editor.entities)[n:]:
            del self.editor.entities[i]
        for i, e in touched.items():
            self.editor.entities[i] = e
        self.editor._index = None  # rebuilt from the registry on the next edit
        self.places.places, self.editor._ord, self._op_seq = places, ord_, op_seq

    def _write(self, key: str, seg: LayeredSegment, v: _Video, turn: int, touchable: list) -> tuple[list[dict], dict]:
        p, dim = self.participant, self.embedder.dim
        before = {e.id: (e.status, e.location) for e in touchable}
        known_places = set(self.places.places)
        old_turns = {k: pp.turn_count for k, pp in self.places.places.items()}
        old_texts = {k: pp.text() for k, pp in self.places.places.items()}
        texts = [seg.activity.summary] + sorted({identity_text(o.name, o.category) for o in seg.objects})
        seg_vec = self.embedder.encode(texts)[0]
        result = self.editor.edit(seg)
        in_place, spatial = self.places.merge(seg)
        new_places = [pp for k, pp in sorted(self.places.places.items()) if k not in known_places]
        changed_places = [pp for k, pp in sorted(self.places.places.items())
                          if k in known_places and pp.turn_count != old_turns[k]]
        # a place seen again whose text (name and zones) is the same keeps the vector this writer
        # wrote for that text: only new places, those whose text changed and those whose vector
        # was not written by this writer yet (a build's embedder wrote it) are embedded and written
        restated = [pp for pp in changed_places
                    if pp.text() != old_texts[pp.location_id] or pp.id not in self._place_vecs]
        place_vecs = self.embedder.encode([pp.text() for pp in new_places + restated]) \
            if new_places or restated else np.zeros((0, dim), np.float32)
        added = set(result.added)
        ents = self.editor.entities
        new_ents = [ents[i] for i in result.added]
        changed = [ents[i] for i in sorted(result.touched) if i not in added]
        relocated = [e.id for e in changed if (e.status, e.location) != before.get(e.id)]
        located = [{"from": e.id, "to": place_id(p, e.location)} for e in new_ents if e.status == "active"]
        located += [{"from": i, "to": place_id(p, ents[i].location)} for i in relocated if ents[i].status == "active"]
        ops, op_rows, edited, merged = [], [], [], []
        for op, obs in result.ops:
            self._op_seq += 1
            oid = f"{p}:op{self._op_seq:07d}"
            ops.append({"id": oid, "op": op.op, "entity": op.entity_id, "object": obs.name, "reason": op.reason,
                        "changes": dict(op.changes), **({"merged_into": op.merged_into} if op.merged_into else {})})
            op_rows.append({"id": oid, "participant": p, "video": seg.video_id, "turn": turn,
                            "t": round(seg.t_start + obs.t_rel, 3), "op": op.op, "entity": op.entity_id,
                            "reason": op.reason, "changes": json.dumps(op.changes, sort_keys=True),
                            "policy": self.editor.policy.name})
            edited.append({"from": oid, "to": op.entity_id})
            if op.merged_into:
                merged.append({"from": op.entity_id, "to": op.merged_into, "video": seg.video_id, "turn": turn})
        sid = seg.segment_id
        seg_row = {"id": sid, "participant": p, "video": seg.video_id, "turn": turn, "t_start": seg.t_start,
                   "t_end": seg.t_end, "summary": seg.activity.summary, "narrative": seg.activity.detailed_narrative,
                   "action_breakdown": json.dumps([a.model_dump() for a in seg.activity.action_breakdown]),
                   "working_summary": seg.working_summary, "location": seg.environment.location_id,
                   "n_actions": len(seg.activity.action_breakdown), "n_objects": len(seg.objects)}
        duration = max(v.duration, seg.t_end)
        answer = {"key": key, "participant": p, "segment": sid, "video": seg.video_id, "turn": turn, "ops": ops}
        # Row by row (UNWIND ... CREATE): a COPY writes whole pages straight into the file and costs
        # 100-300 ms to commit where a small CREATE transaction costs a few (measured here).
        with self._conn_lock:
            self._transaction(key, seg, v, turn, answer, seg_row, seg_vec, new_places, changed_places, restated,
                              place_vecs,
                              new_ents, changed, relocated, located, in_place, spatial, result, op_rows, merged,
                              duration)
        with self._store_lock:  # (the same lock, unless the readers read apart)
            # committed: the key is acknowledged and the vectors written (even if on_commit fails)
            self._keys.add(key)
            self.commits += 1
            self._place_vecs.update(pp.id for pp in new_places + restated)
            delta = {"segment": sid, "video": seg.video_id, "entities": sorted(result.touched),
                     "segment_row": {"id": sid, "emb": seg_vec, "summary": seg_row["summary"],
                                     "narrative": seg_row["narrative"], "video": seg.video_id,
                                     "t_start": seg.t_start, "action_breakdown": seg_row["action_breakdown"]},
                     "places": [pp.location_id for pp in new_places + changed_places],
                     "observations": [(ev["entity"], ev["location"]) for ev in result.events if ev["action"]],
                     "history": sorted({ev["entity"] for ev in result.events}),  # whose state history grew
                     "entries": [{k: ev[k] for k in _EVENT} for ev in result.events],  # the new history entries
                     "merged": [(m["from"], m["to"]) for m in merged],
                     # the Entity columns as written (a reader takes them in without reading them back)
                     "entity_rows": {**{e.id: ({k: getattr(e, k) for k in _ENTITY_UPDATE} if len(changed) <= _SCALAR_ROWS
                                               else entity_row(e)) for e in changed},
                                     **{e.id: {**entity_row(e), "emb": _floats(e.emb if e.emb is not None else
                                                                             np.zeros(dim, np.float32))}
                                        for e in new_ents}}}
            self.journal.append(delta)
            if self._on_commit is not None:
                self._on_commit(delta)
        return ops, delta

    def _transaction(self, key, seg, v, turn, answer, seg_row, seg_vec, new_places, changed_places, restated,
                     place_vecs,
                     new_ents, changed, relocated, located, in_place, spatial, result, op_rows, merged,
                     duration) -> None:
        p, dim, sid = self.participant, self.embedder.dim, seg.segment_id
        with self.store.transaction():
            if seg.video_id not in self.videos:
                # its length, turns and actions are the moment's statement's to set
                self._add("_live_add_video", [{"id": seg.video_id, "duration": duration, "n_turns": turn + 1,
                                               "n_actions": 0, "mode": self.mode, "built_at": _now(),
                                               "build_seconds": 0.0}])
            # Places and entities first (the moment's edges point at them), then one statement for
            # the moment itself: the video grown, the segment (and its NEXT edge), its
            # acknowledgement and its IN_PLACE edges, every id bound as a scalar so Kùzu looks it
            # up in the primary-key index (an id from an UNWIND row scans the table, which grows
            # with the hours of memory).
            self._add("_live_add_places", [{**place_row(pp), "emb": _floats(vec)}
                                           for pp, vec in zip(new_places, place_vecs[: len(new_places)])])
            # A place seen again gets its merged zones, features and sightings through the moment's
            # IN_PLACE row (below); one whose text changed gets its new vector here, a statement
            # per place (its id bound as a scalar: cheaper for Kùzu than an UNWIND over rows).
            vecs = {pp.id: vec for pp, vec in zip(restated, place_vecs[len(new_places):])}
            for pp in changed_places:
                if pp.id in vecs:
                    self._one("_live_place_update", id=pp.id, zones=pp.zones, features=pp.features,
                              last_seen=pp.last_seen, last_video=pp.last_video, turn_count=pp.turn_count,
                              emb=_floats(vecs[pp.id]))
            self._add("_live_add_entities", [{**entity_row(e), "emb": _floats(e.emb if e.emb is not None else
                                                                                np.zeros(dim, np.float32))}
                                             for e in new_ents])
            # The common edit (an existing entity changed, with one operation and one state event
            # on it) is one statement after the moment's (`_live_edit`); the others, one statement
            # per row here (ids bound as scalars) or, past a few rows, one UNWIND.
            events = [{**{k: ev[k] for k in _EVENT}, "place": place_id(p, ev["location"])} for ev in result.events]
            edits, events, op_rows = self._edits(changed, events, op_rows) if len(changed) <= _SCALAR_ROWS \
                else ([], events, op_rows)
            if len(changed) <= _SCALAR_ROWS:
                edited_ids = {e.id for e, _, _ in edits}
                for e in changed:
                    if e.id not in edited_ids:
                        self._one("_live_entity_update", **{k: getattr(e, k) for k in _ENTITY_UPDATE})
            else:
                self.store.write("_entity_update", participant=p, rows=[entity_row(e) for e in changed])
            if len(relocated) <= _SCALAR_ROWS:
                for eid in relocated:
                    self.store.write("_live_located_at_clear", participant=p, id=eid)
            else:
                self.store.write("_located_at_clear", participant=p, ids=relocated)
            if len(located) <= _SCALAR_ROWS:
                for r in located:
                    self._one("_live_located_at", id=r["from"], place=r["to"])
            else:
                self._add("_live_add_located", located)
            places = {pp.id: pp for pp in self.places.places.values()}
            rows = [{**r, "place_zones": places[r["to"]].zones, "features": places[r["to"]].features,
                     "last_seen": places[r["to"]].last_seen, "last_video": places[r["to"]].last_video,
                     "turn_count": places[r["to"]].turn_count} for r in in_place]
            moment = {**seg_row, "emb": _floats(seg_vec), "duration": duration, "key": key,
                      "result": json.dumps(answer), "at": _now(), "rows": rows}
            if v.last_segment is not None:
                got = int(self.store.write("_live_add_moment_next", prev=v.last_segment, **moment)[0]["n"])
            else:
                got = int(self.store.write("_live_add_moment", **moment)[0]["n"])
            if got != len(in_place) or not in_place:
                missing = f"the previous segment {v.last_segment} or " if v.last_segment else ""
                raise StoreError(f"{self.store.path}: the moment's segment was not written ({missing}its video "
                                 f"{seg.video_id} or one of its places is missing); nothing of this moment was kept")
            self._add("_live_add_spatial", spatial)
            for e, ev, op in edits:
                self._one("_live_edit", **{k: getattr(e, k) for k in _ENTITY_UPDATE}, segment=sid, place=ev["place"],
                          op_id=op["id"], op_video=op["video"], op_turn=op["turn"], op_t=op["t"], op=op["op"],
                          reason=op["reason"], changes=op["changes"], policy=op["policy"], ev_id=ev["id"],
                          ev_video=ev["video"], ev_turn=ev["turn"], ev_t=ev["t"], ord=ev["ord"], ev_state=ev["state"],
                          ev_location=ev["location"], prev_state=ev["prev_state"], prev_location=ev["prev_location"],
                          zone=ev["zone"], ev_held_by=ev["held_by"], relative_to=ev["relative_to"],
                          relation=ev["relation"], action=ev["action"], narration=ev["narration"], ev_op=ev["op"])
            if len(events) <= _SCALAR_ROWS:  # the common case: a statement per row, ids bound as scalars
                for ev in events:
                    self._one("_live_add_event", segment=sid, **ev)
            else:
                self._add("_live_add_events", events, segment=sid)
            if len(op_rows) <= _SCALAR_ROWS:
                for op in op_rows:
                    self._one("_live_add_op", **{k: op[k] for k in op if k != "participant"})
            else:
                self._add("_live_add_ops", op_rows)
            self._add("_live_add_merged", merged)

    @staticmethod
    def _edits(changed: list, events: list[dict], op_rows: list[dict]) -> tuple[list[tuple], list[dict], list[dict]]:
        """The changed entities with exactly one operation and one state event on them, each
        with those (one `_live_edit` statement apiece), and the events and operations left."""
        n_ev, n_op = {}, {}
        for ev in events:
            n_ev[ev["entity"]] = n_ev.get(ev["entity"], 0) + 1
        for op in op_rows:
            n_op[op["entity"]] = n_op.get(op["entity"], 0) + 1
        paired = {e.id for e in changed if n_ev.get(e.id) == 1 and n_op.get(e.id) == 1}
        if not paired:
            return [], events, op_rows
        ev_of = {ev["entity"]: ev for ev in events if ev["entity"] in paired}
        op_of = {op["entity"]: op for op in op_rows if op["entity"] in paired}
        edits = [(e, ev_of[e.id], op_of[e.id]) for e in changed if e.id in paired]
        return (edits, [ev for ev in events if ev["entity"] not in paired],
                [op for op in op_rows if op["entity"] not in paired])

    def _one(self, name: str, **params) -> None:
        """Run one of the live writer's single-row statements (ids bound as scalars); its row must
        land (a missing entity, place or segment would otherwise drop it silently)."""
        if int(self.store.write(name, participant=self.participant, **params)[0]["n"]) != 1:
            raise StoreError(f"{self.store.path}: {name} wrote nothing for {params.get('id')!r} (a missing entity, "
                             "place or segment); nothing of this moment was kept")

    def _add(self, name: str, rows: list[dict], **params) -> None:
        """Run one of the live writer's CREATE queries; every row must land (a row whose
        endpoints are missing would otherwise vanish silently): else the transaction fails."""
        if not rows:
            return
        got = int(self.store.write(name, participant=self.participant, rows=rows, **params)[0]["n"])
        if got != len(rows):
            raise StoreError(f"{self.store.path}: {name} wrote {got} of {len(rows)} rows (a missing entity, place or "
                             "segment); nothing of this moment was kept")
