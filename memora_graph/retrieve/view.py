"""A participant's memory opened for the retrieval tools: one read-only store, one participant.

The view is the unit of scoping: it holds exactly one participant's database and binds that
participant into every named query it runs, so no tool can return another person's records.
Small tables that every call needs (the entity registry, places, videos, inferred knowledge,
embedding matrices, the entity-segment observation graph) are loaded once, through named
queries, the first time a tool needs them; per call the tools run the keyword search and fetch
the large tables (segments, state history) with prepared named queries.
"""

from __future__ import annotations

import bisect
import gc
import json
import logging
import os
import threading
import time
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from memora_graph.bank import Bank
from memora_graph.embed import single_thread_blas
from memora_graph.errors import BankError, MemoraError
from memora_graph.retrieve.embedding import QueryEncoder
from memora_graph.retrieve.graph import ObservationGraph
from memora_graph.retrieve.history import HistoryIndex, HistoryParts, appended_parts, outline_parts
from memora_graph.retrieve.search import DEFAULT_RECIPE, HNSW_MIN_SEGMENTS, RECIPES, TABLES, Bm25, SearchConfig, \
    VectorTable
from memora_graph.retrieve.steps import StepRows
from memora_graph.retrieve.tasks import TaskIndex

if TYPE_CHECKING:
    from memora_graph.retrieve.persist import PersistedStores
    from memora_graph.store import Store

_HNSW_TABLES = ("segment", "entity")  # the tables schema/indexes/hnsw.cypher indexes
log = logging.getLogger("memora_graph.integrity")
TOOL_STORES_ENV = "MEMORA_TOOL_STORES"  # "0": read Kùzu, never the persisted stores
STEPS_PENDING_MAX = 512  # remembered segments held for the activity log's next read before they are put in


# Views whose loaded data `warm` froze (gc.freeze is process-wide: the permanent generation holds
# every warm view's objects). The last of them to close unfreezes: closing one view while another
# stays open must not hand the open view's objects back to the cyclic collector.
_FROZEN = {"views": 0}
_FROZEN_LOCK = threading.Lock()


def _freeze() -> None:
    with _FROZEN_LOCK:
        gc.freeze()  # what was loaded since (this view's) joins the permanent generation
        _FROZEN["views"] += 1


def _thaw() -> None:
    with _FROZEN_LOCK:
        _FROZEN["views"] -= 1
        if _FROZEN["views"] == 0:
            gc.unfreeze()  # what every warm view froze can be collected again (a cycle among it included)


class ToolError(MemoraError):
    """A tool called with arguments it cannot answer (the message says what would work)."""


def _config(config: SearchConfig | str) -> SearchConfig:
    if isinstance(config, str) and config not in RECIPES:
        raise ToolError(f"no retrieval recipe {config!r}; recipes: {', '.join(RECIPES)}")
    return RECIPES[config] if isinstance(config, str) else config


def _recipe_by_size(entry: dict) -> str:
    """`MemoryView.auto_recipe` from a manifest entry, without opening the database."""
    from memora_graph.store import index_names

    indexed = (set(index_names("fts")) | set(index_names("hnsw"))) <= set(entry.get("indexes") or ())
    big = HNSW_MIN_SEGMENTS is not None and (entry.get("counts") or {}).get("segments", 0) >= HNSW_MIN_SEGMENTS
    return "hnsw" if indexed and big else DEFAULT_RECIPE


class MemoryView:
    def __init__(self, store: Store | None, participant: str, embedder=None,
                 config: SearchConfig | str | None = None, owns_store: bool = False,
                 persisted: PersistedStores | None = None, open_store=None):
        """`store` is the participant's open database; or None with `persisted` stores (read
        instead of Kùzu for what they hold) and `open_store()` to open the database when a tool
        needs something else (`MemoryView.open` does that). `config`: a recipe name (RECIPES) or a
        SearchConfig; None picks one by the memory's size (`auto_recipe`)."""
        single_thread_blas()
        self._store = store
        self._open_store = open_store
        self._persisted = persisted
        self.persisted_written: Path | None = None  # where `open(..., persist=True)` wrote the stores
        self.participant = participant
        if config is None:
            config = self.auto_recipe() if store is not None else DEFAULT_RECIPE
        self.recipe = config if isinstance(config, str) else None
        self.config = _config(config)
        self._embedder = embedder
        self._owns = owns_store
        self.notes: list[str] = []  # degradations a caller should know about (none at present)
        if store is None:
            if persisted is None or open_store is None:
                raise ValueError("a MemoryView needs a store, or persisted stores and a way to open the store")
            return  # the persisted stores were written by a view that passed the checks below
        migrations = set(store.migrations())
        if "002_inferred.cypher" not in migrations:
            raise BankError(f"{store.path}: built before inferred knowledge existed (schema 002 missing); "
                            "rebuild it with `memora build`")
        self._check_indexes(config)

    def auto_recipe(self) -> str:
        """The recipe a view opens with when none is asked for: the default ('inprocess', exact
        numpy top-k and in-process BM25, which load the participant's vectors and texts and scan
        them per call), or 'hnsw' (Kùzu's HNSW and FTS indexes) for a memory of at least
        HNSW_MIN_SEGMENTS segments whose database has those indexes: from that size on the
        indexed recipe measured faster (`memora perf scale`). Without the indexes it stays exact."""
        from memora_graph.store import index_names

        if HNSW_MIN_SEGMENTS is None:
            return DEFAULT_RECIPE  # no measured size has HNSW faster (retrieve/search.py)
        have = set(self.store.indexes())
        if not have or not (set(index_names("fts")) | set(index_names("hnsw"))) <= have:
            return DEFAULT_RECIPE  # most banks: one index listing, no count
        n = self.fetch("_segment_count")[0]["n"]
        return "hnsw" if n >= HNSW_MIN_SEGMENTS else DEFAULT_RECIPE

    def _check_indexes(self, config: SearchConfig | str) -> None:
        """A recipe that reads Kùzu's optional indexes fails here, saying how to build them,
        rather than on its first call. Builds make none by default ('inprocess' needs none)."""
        from memora_graph.store import index_names

        kinds = [k for k, on in (("fts", self.config.keyword == "fts"), ("hnsw", self.config.vector == "hnsw")) if on]
        if not kinds:
            return
        have = set(self.store.indexes())
        missing = {k: sorted(set(index_names(k)) - have) for k in kinds}
        missing = {k: v for k, v in missing.items() if v}
        if not missing:
            return
        what = {"fts": "full-text (FTS)", "hnsw": "HNSW vector"}
        recipe = f"the '{config}' recipe" if isinstance(config, str) else "this retrieval config"
        bank = self.store.path.parent
        at_build = " (or pass --fts to `memora build`)" if list(missing) == ["fts"] else ""
        raise ToolError(
            f"{self.store.path}: {recipe} needs the {' and '.join(what[k] for k in missing)} indexes, which this "
            f"database does not have (missing: {', '.join(n for v in missing.values() for n in v)}). Build them with "
            f"`memora index {bank} {' '.join('--' + k for k in missing)}`{at_build}, or use the default recipe "
            f"'{DEFAULT_RECIPE}', which needs none.")

    @classmethod
    def open(cls, bank: str | Path, participant: str, embedder=None, config: SearchConfig | str | None = None,
             persist: bool | None = None, keep_loaded: bool = True) -> MemoryView:
        """Open a participant's memory read-only. With `persist` and an in-process recipe, the
        stores persisted next to the bank (memora_graph/retrieve/persist.py) are read when they
        match the database's recorded sha256, and Kùzu is opened only if a tool needs more; when
        they are missing, stale or damaged they are computed from the database and written.
        `persist` defaults to on unless MEMORA_TOOL_STORES=0. With no `config`, the recipe is
        picked as `auto_recipe` does, from the manifest's record (indexes, segments).
        `keep_loaded=False` (writing the stores is all the caller wants): each part is dropped
        once written, so that what the write holds does not add up part after part."""
        if persist is None:
            persist = os.environ.get(TOOL_STORES_ENV, "1") != "0"
        b = Bank(bank)
        if config is None:
            config = _recipe_by_size(b.manifest().get("participants", {}).get(participant, {}))
        cfg = _config(config)
        sha = None
        if persist and cfg.vector == "numpy" and cfg.keyword in ("bm25", "none"):
            from memora_graph.retrieve.persist import PersistedStores, StaleStores

            sha = b.checked_sha256(participant)
            embed_model = b.manifest().get("embed_model")
            if sha is not None:
                try:
                    stores = PersistedStores.open(bank, participant, sha, embed_model)
                except StaleStores as why:
                    if why.damaged:  # stale is expected after any write; damage is worth a word
                        log.warning(f"{why}; reading the database instead (and writing them again)")
                else:
                    view = cls(None, participant, embedder, config, owns_store=True, persisted=stores,
                               open_store=lambda: b.open(participant, read_only=True))
                    view.replay(stores.journal)
                    return view
        store = b.open(participant, read_only=True)
        try:
            view = cls(store, participant, embedder, config, owns_store=True)
        except BaseException:
            store.close()
            raise
        if sha is not None and _writable(Path(bank)):
            from memora_graph.retrieve.persist import write

            try:
                view.persisted_written = write(view, bank, sha, b.manifest().get("embed_model"), release=not keep_loaded)
            except OSError as exc:  # a full or read-only disk: the view works without them
                log.warning(f"{bank}: could not persist {participant}'s tool stores ({exc})")
        return view

    @classmethod
    def live(cls, store: Store, bank: str | Path, participant: str, db_sha256: str | None, embedder=None,
             config: SearchConfig | str = DEFAULT_RECIPE, own: bool = False) -> MemoryView:
        """`_live`'s view; `own`: the view closes `store` when it closes (a reader connection
        of the writer's database, `Store.reader`, opened for it)."""
        view = cls._live(store, bank, participant, db_sha256, embedder, config)
        view._owns = own
        return view

    @classmethod
    def _live(cls, store: Store, bank: str | Path, participant: str, db_sha256: str | None, embedder=None,
              config: SearchConfig | str = DEFAULT_RECIPE) -> MemoryView:
        """A view for the readers of a live writer (`memora serve --writable`), on the writer's own
        `store` (read-write, not closed by the view). `db_sha256`: the database's sha256 as the
        writer opened it, checked against its integrity record (form/live.py `opened_sha256`),
        given only while nothing was written since. With an in-process recipe the persisted tool
        stores are read when they were computed from exactly that database, and written first
        from the store when they are missing or stale (as `open` does); remembered moments then
        reach the view through `absorb`, which reads what they touched from the store until the
        stores are written again. A later open never trusts these stores once the writer wrote:
        the writer's close (or the recovery of a killed writer) records the database's new
        sha256, which the stores do not carry. None, --no-verify or MEMORA_TOOL_STORES=0: the
        store only."""
        cfg = _config(config)
        persist = os.environ.get(TOOL_STORES_ENV, "1") != "0"
        if not (db_sha256 and persist and cfg.vector == "numpy" and cfg.keyword in ("bm25", "none")):
            return cls(store, participant, embedder, config)
        from memora_graph.retrieve.persist import PersistedStores, StaleStores, write

        embed_model = Bank(bank).manifest().get("embed_model")
        try:
            stores = PersistedStores.open(bank, participant, db_sha256, embed_model)
        except StaleStores as why:
            if why.damaged:
                log.warning(f"{why}; reading the database instead (and writing them again)")
            if not _writable(Path(bank)):
                return cls(store, participant, embedder, config)
            view = cls(store, participant, embedder, config)
            try:
                written = write(view, bank, db_sha256, embed_model)
                stores = PersistedStores.open(bank, participant, db_sha256, embed_model)
            except (OSError, StaleStores) as exc:  # a full disk: the view works on the store
                log.warning(f"{bank}: could not persist {participant}'s tool stores ({exc})")
                return view
            view.close()
            out = cls(None, participant, embedder, config, persisted=stores, open_store=lambda: store)
            out.persisted_written = written
            out._store = store  # open already; the view does not own it
            return out
        out = cls(None, participant, embedder, config, persisted=stores, open_store=lambda: store)
        out._store = store
        out.replay(stores.journal)
        return out

    @property
    def store(self) -> Store:
        if self._store is None:
            self._store = self._open_store()
        return self._store

    def interrupt(self) -> None:
        """Stop the Kùzu query this view runs now, if any (a served call past its time budget)."""
        if self._store is not None:
            self._store.interrupt()

    def close(self) -> None:
        if self._owns and self._store is not None:
            self._store.close()
        if self.__dict__.pop("_frozen", False):
            _thaw()

    def __enter__(self) -> MemoryView:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- queries and embeddings ---------------------------------------------------------
    def fetch(self, name: str, **params) -> list[dict]:
        if not params and self._persisted is not None and self._persisted.has_rows(name) \
                and name not in self.__dict__.get("_rows_changed", ()):
            got = self._from_persisted(lambda p: p.rows(name))
            if got is not None:
                return got
        if len(params) == 1 and self._persisted is not None:  # a video's entries, kept (retrieve/rows.py)
            keyed = self._keyed(name)
            value = next(iter(params.values()))
            if keyed is not None and keyed.grouped and value not in self.__dict__.get("_keys_added", ()):
                return keyed.rows(value)
        return self.store.fetch(name, participant=self.participant, **params)

    def by_id(self, name: str, ids: list[str]) -> list[dict]:
        """The rows of a one-id named query for each id, in order (an id not found gives none):
        from the rows kept with the persisted stores (retrieve/rows.py) where they hold that
        query, else a prepared lookup by key each, where a filter over ids reads the whole table."""
        keyed = self._keyed(name)
        if keyed is None or keyed.grouped:
            return [r for i in ids for r in self.store.fetch(name, participant=self.participant, id=i)]
        added = self.__dict__.get("_keys_added", ())
        out = []
        for i in ids:
            if i in added:
                out += self.store.fetch(name, participant=self.participant, id=i)
            else:
                r = keyed.get(i)
                if r is not None:
                    out.append(r)
        return out

    def _keyed(self, name: str):
        """The rows of named query `name` kept with the persisted stores (retrieve/rows.py), or None."""
        cache = self.__dict__.setdefault("_keyed_cache", {})
        if name not in cache:
            held = self._persisted is not None and self._persisted.has_keyed(name)
            cache[name] = self._from_persisted(lambda p: p.keyed(name)) if held else None
        return cache[name]

    def frame(self, name: str, **params):
        """A named query's rows as a polars frame (one columnar fetch: for many thin rows)."""
        return self.store.fetch_frame(name, participant=self.participant, **params)

    def _from_persisted(self, read):
        """`read(persisted)`, or None (and the persisted stores dropped, with a warning) when a
        file turns out damaged: the database is read instead."""
        from memora_graph.retrieve.persist import StaleStores

        try:
            return read(self._persisted)
        except StaleStores as why:
            log.warning(f"{why}; reading the database instead")
            self._persisted = None
            return None

    @cached_property
    def encoder(self) -> QueryEncoder:
        if self._embedder is None:
            from memora_graph.embed import get_embedder

            self._embedder = get_embedder()
        return QueryEncoder(self._embedder)

    def embed(self, text: str) -> np.ndarray:
        return self.encoder(text)

    def prefetch(self, texts: list[str]) -> None:
        """Embed the queries of a batch of calls at once (an agent response carrying several)."""
        self.encoder.prefetch(texts)

    # -- loaded once ----------------------------------------------------------------------
    def release(self, table: str | None = None) -> None:
        """Drop what the view loaded of `table` (its vectors and BM25 index), or with no table
        the observation graph; read again when next used."""
        if table is None:
            self.__dict__.pop("graph", None)
        else:
            self.__dict__.get("_vector_cache", {}).pop(table, None)
            self.__dict__.get("_bm25_cache", {}).pop(table, None)

    def vectors(self, table: str) -> VectorTable:
        got = self._grown("vectors", table)  # loaded, or read now from the persisted stores
        if got is None:
            got = self.__dict__["_vector_cache"][table] = self._vectors_from_store(table)
        return got

    def _vectors_from_store(self, table: str) -> VectorTable:
        """One columnar fetch straight into a float32 matrix: as rows, each vector was 384 Python
        floats (gigabytes at 1,000 h, when the tool stores are written)."""
        import polars as pl

        frame = self.frame(f"_tool_vectors_{table}").filter(pl.col("emb").is_not_null())
        if not frame.height:
            return VectorTable([], np.zeros((0, 1), np.float32))
        return VectorTable(frame["id"].to_list(), frame["emb"].to_numpy())

    @cached_property
    def entities(self) -> dict[str, dict]:
        return {r["id"]: r for r in self.fetch("_tool_entities")}

    @cached_property
    def active_entities(self) -> dict[str, dict]:
        return {i: e for i, e in self.entities.items() if e["status"] == "active"}

    @cached_property
    def max_observations(self) -> int:
        return max((e["n_observations"] or 0 for e in self.active_entities.values()), default=0)

    @cached_property
    def places(self) -> dict[str, dict]:
        """location_id -> place row."""
        return {r["location_id"]: r for r in self.fetch("_tool_places")}

    @cached_property
    def videos(self) -> dict[str, dict]:
        return {r["id"]: r for r in self.fetch("_tool_videos")}

    @cached_property
    def routines(self) -> dict[str, dict]:
        """Every routine's row by id, its `detail` as stored (JSON text holding every supporting
        episode: 9.5 MB at 1,000 h, 0.3 CPU-s to parse at each open): `routine_detail` parses a
        routine's when a record needs it."""
        return {r["id"]: r for r in self.fetch("_tool_routines")}

    def routine_detail(self, rid: str) -> dict:
        """The parsed `detail` of routine `rid` (parsed once per row loaded: a row read again after
        a consolidation is parsed again)."""
        row = self.routines[rid]
        parsed = self.__dict__.setdefault("_routine_details", {})
        got = parsed.get(rid)
        if got is None or got[0] is not row:
            got = parsed[rid] = (row, json.loads(row["detail"] or "{}"))
        return got[1]

    @cached_property
    def tasks(self) -> TaskIndex:
        """The participant's tasks, indexed by the object kinds they name (retrieve/tasks.py): read
        whole once, for every plan the view makes; a consolidation (`reload_inferred`) drops them."""
        return TaskIndex.read(self.store, self.participant)

    @cached_property
    def preferences(self) -> dict[str, dict]:
        return {r["id"]: {**r, "detail": json.loads(r["detail"] or "{}")} for r in self.fetch("_tool_preferences")}

    @cached_property
    def graph(self) -> ObservationGraph:
        if self._persisted is not None and self._persisted.has_graph():
            got = self._from_persisted(lambda p: p.graph())
            if got is not None:
                return got
        return ObservationGraph(self.frame("_tool_observations").iter_rows(named=True))  # rows one at a time

    @cached_property
    def history(self) -> HistoryIndex | None:
        """Every entity's history summary, from the persisted stores (None without them: each call
        then reads the entity's outline from Kùzu)."""
        if self._persisted is not None and self._persisted.has_history():
            return self._from_persisted(lambda p: p.history())
        return None

    def history_parts(self, entity: str, max_entries: int) -> HistoryParts:
        """What get_object_history answers with from an entity's history: from the history index
        (a bounded read), or from the entity's outline in Kùzu when there is no index or a
        remembered moment added to the entity's history since the index was written."""
        if self.history is not None and entity not in self.__dict__.get("_history_added", ()):
            added = self.__dict__.get("_history_appended", {}).get(entity)
            if added:  # entries remembered after the index's last: appended to its parts
                return appended_parts(self.history.parts(entity, max_entries), self.history.last(entity), added,
                                      max_entries)
            return self.history.parts(entity, max_entries)
        return outline_parts(self.frame("_tool_history_outline", entity=entity), max_entries)

    def _history_absorbed(self, delta: dict) -> None:
        """Note whose history a remembered moment changed. With the history index, an entity whose
        new entries (handed over by the writer: `delta["entries"]`) all come after its last one in
        history order (video, time) has them appended to the index's parts; any other (an entry
        within its history, a merge, no entries handed over) is read from Kùzu until the stores are
        written again."""
        loaded = self.__dict__
        kuzu = loaded.setdefault("_history_added", set())
        appended = loaded.setdefault("_history_appended", {})
        grown = set(delta.get("history", delta.get("entities", [])))
        grown.update(e for e, _ in delta.get("observations", []))
        entries: dict[str, list[dict]] = {}
        for e in sorted(delta.get("entries") or [], key=lambda e: (e["entity"], e["video"], e["t"], e["ord"])):
            entries.setdefault(e["entity"], []).append(e)
        merged = {x for pair in delta.get("merged", []) for x in pair}
        index = self.history if "entries" in delta else None
        for entity in grown | set(entries) | merged:
            new = entries.get(entity)
            if entity in kuzu or index is None or entity in merged or not new:
                kuzu.add(entity)
                appended.pop(entity, None)
                continue
            before = appended.get(entity)
            last = (before[-1]["video"], before[-1]["t"]) if before else (index.last(entity) or (None,))[:2]
            if last[0] is not None and (new[0]["video"], new[0]["t"]) <= last:
                kuzu.add(entity)  # within its history: the outline from Kùzu
                appended.pop(entity, None)
            else:
                appended.setdefault(entity, []).extend(new)

    # -- signals ---------------------------------------------------------------------------
    def knn(self, table: str, q: np.ndarray, k: int) -> list[tuple[str, float]]:
        if self.config.vector == "numpy":
            return self.vectors(table).topk(q, k)
        if self.config.vector == "hnsw" and table in _HNSW_TABLES:
            rows = self.fetch(f"_tool_hnsw_{table}", vector=q.tolist())
        else:
            rows = self.fetch(f"_tool_knn_{table}", vector=q.tolist())
        return [(r["id"], float(r["sim"])) for r in rows[:k]]

    def keyword(self, table: str, query: str, k: int) -> list[tuple[str, float]]:
        if self.config.keyword == "none" or not query.strip():
            return []
        if self.config.keyword == "fts":
            if not any(c.isalpha() for c in query):
                return []  # Kùzu's FTS drops digits; a query without letters matches nothing
            return [(r["id"], float(r["score"])) for r in self.fetch(f"_tool_fts_{table}", query=query)[:k]]
        return self._bm25(table).search(query, k)

    def bm25(self, table: str) -> Bm25:
        return self._bm25(table)

    def _bm25(self, table: str) -> Bm25:
        got = self._grown("bm25", table)  # loaded, or read now from the persisted stores
        if got is not None:
            return got
        if table == "segment":
            rows = self.frame("_tool_segment_texts").iter_rows(named=True)
            docs = [(r["id"], f"{r['summary']} {r['narrative']}") for r in rows]
        elif table == "entity":
            docs = [(i, f"{e['name']} {e['kind']} {e['category']}") for i, e in self.entities.items() if e["status"] == "active"]
        elif table == "place":
            docs = [(p["id"], p["name"]) for p in self.places.values()]
        elif table == "routine":
            docs = [(i, r["retrieval_text"]) for i, r in self.routines.items()]
        else:
            docs = [(i, r["retrieval_text"]) for i, r in self.preferences.items()]
        got = self.__dict__["_bm25_cache"][table] = Bm25([d[0] for d in docs], [d[1] for d in docs])
        return got

    # -- a memory that grows while it is read (live memory: `memora serve --writable`) -------------
    _ENTITY_DERIVED = ("entities", "active_entities", "max_observations", "_entity_words", "_objects_at", "_link_kinds",
                       "_object_names")
    # of those, what depends only on the entities' words (ids, names, kinds: kept while a remember
    # changes no entity's words) and what on their places, states and counts (dropped at every change)
    _ENTITY_WORDS = ("_entity_words", "_link_kinds", "_object_names")
    _ENTITY_STATE = ("active_entities", "max_observations", "_objects_at")
    # what a remember or a consolidation changes, by table: the participant-wide rows read again from
    # the store from then on (the persisted ones describe the database before it)
    _ROWS_OF = {"entity": "_tool_entities", "place": "_tool_places", "routine": "_tool_routines",
                "preference": "_tool_preferences"}

    def _persisted_for(self, table: str) -> bool:
        """Whether the persisted stores still describe `table`'s vectors and keywords."""
        return self._persisted is not None and table not in self.__dict__.get("_tables_changed", ())

    def _changed(self, *tables: str, rows: tuple[str, ...] = ()) -> None:
        """Tables (and participant-wide row queries) the database changed since the persisted
        stores were computed: read from the store from now on, not from the stores."""
        loaded = self.__dict__
        loaded.setdefault("_tables_changed", set()).update(tables)
        loaded.setdefault("_rows_changed", set()).update((*(self._ROWS_OF[t] for t in tables), *rows))

    def _grown(self, kind: str, table: str | None = None):
        """The loaded vectors / keywords of `table` or the graph; loaded from the persisted stores
        now if not yet; None where neither holds them. `vectors` and `_bm25` then compute them
        from the store; `absorb` adds a remembered moment to what it returns (the persisted
        stores lack the moment), or to nothing where it returns None (a later load from the store
        reads the moment)."""
        loaded = self.__dict__
        if kind == "graph":
            if "graph" not in loaded and self._persisted is not None and self._persisted.has_graph():
                got = self._from_persisted(lambda p: p.graph())
                if got is not None:
                    loaded["graph"] = got
            return loaded.get("graph")
        cache = loaded.setdefault("_vector_cache" if kind == "vectors" else "_bm25_cache", {})
        if table not in cache and self._persisted_for(table):
            got = self._from_persisted(lambda p: p.vectors(table) if kind == "vectors" else p.bm25(table))
            if got is not None:
                cache[table] = got
        return cache.get(table)

    def absorb(self, delta: dict) -> None:
        """Bring what this view loaded up to date with one remembered moment (form/live.py's
        `Remembered.delta`), without reloading the participant: the new segment's vector and text
        are appended, the new observations join the observation graph, and the small
        participant-wide tables the moment touched (entities, places, videos) are read again on
        their next use. Called by the one thread that writes, under the lock the readers take."""
        loaded = self.__dict__
        sid = delta["segment"]
        seg_vectors, seg_bm25 = self._grown("vectors", "segment"), self._grown("bm25", "segment")
        if seg_vectors is not None or seg_bm25 is not None:
            row = delta.get("segment_row") or self.store.fetch("_live_segment_row", participant=self.participant,
                                                               id=sid)[0]  # the writer hands it over: no read
            if seg_vectors is not None:
                emb = np.asarray(row["emb"], dtype=np.float32)
                loaded["_vector_cache"]["segment"] = seg_vectors.appended(sid, emb)
            if seg_bm25 is not None:
                loaded["_bm25_cache"]["segment"] = seg_bm25.added(sid, f"{row['summary']} {row['narrative']}")
        vectors, bm25 = loaded.get("_vector_cache", {}), loaded.get("_bm25_cache", {})  # every table's
        if delta.get("entities"):
            self._changed("entity")
            kept = self._entities_absorbed(delta["entities"], delta.get("entity_rows") or {})
            for name in self._ENTITY_DERIVED:
                if kept is None or name in self._ENTITY_STATE or (kept and name in self._ENTITY_WORDS):
                    loaded.pop(name, None)
            if kept is None:
                vectors.pop("entity", None)
            if kept is not False:  # an entity added, renamed, merged or revived: the keyword index is rebuilt
                bm25.pop("entity", None)
        if delta.get("places"):
            loaded.pop("places", None)
            vectors.pop("place", None)
            bm25.pop("place", None)
            self._changed("place")
        loaded.pop("videos", None)
        if "_steps" in loaded or (self._persisted is not None and self._persisted.has_steps()):
            row = delta.get("segment_row") or {}  # the activity log's steps (retrieve/steps.py) take it in when read
            pending = loaded.setdefault("_steps_pending", [])
            pending.append(row if "action_breakdown" in row else sid)
            if len(pending) >= STEPS_PENDING_MAX:  # a long stream with no `ask`: folded in now and then, not held
                _ = self.steps
        self._changed(rows=("_tool_videos",))
        loaded.setdefault("_keys_added", set()).update((sid, delta.get("video")))  # rows the kept ones lack
        self._history_absorbed(delta)  # entities whose history grew
        graph = self._grown("graph")
        if graph is not None:
            graph.add(sid, delta.get("observations", []))

    def replay(self, journal: list[dict]) -> None:
        """Take in the moments remembered since the persisted stores were written (their journal,
        form/live_journal.py), as a writable server's readers took each in when it was remembered:
        the stores are not computed or written again. The entity registry and vectors are loaded
        from the stores first, so that the moments' entities are taken in by id, not read whole
        from the database."""
        if not journal:
            return
        t0 = time.perf_counter()
        if any(d.get("entities") for d in journal):
            _ = self.entities
            if self._persisted_for("entity"):
                self.vectors("entity")
        for delta in journal:
            if delta.get("inferred"):
                self.reload_inferred()
            else:
                self.absorb(delta)
        self.replayed = (len(journal), time.perf_counter() - t0)

    @property
    def steps(self) -> StepRows:
        """Every narrated step of the participant as columns (retrieve/steps.py): from the
        persisted stores (else read from the database once), with the segments remembered since
        (`absorb`) put in their place when next read."""
        loaded = self.__dict__
        rows = loaded.get("_steps")
        if rows is None:
            if self._persisted is not None and self._persisted.has_steps():
                rows = self._from_persisted(lambda p: p.steps())
            if rows is None:  # the database holds every remembered segment already
                loaded.pop("_steps_pending", None)
                rows = StepRows.build(self.store.fetch_frame("_open_action_log", participant=self.participant)
                                      .iter_rows(named=True))
        pending = loaded.pop("_steps_pending", None)
        if pending:
            ids = [p for p in pending if isinstance(p, str)]
            read = {r["id"]: r for r in self.by_id("_tool_segment", ids)} if ids else {}
            rows = rows.added([p if not isinstance(p, str) else read[p] for p in pending
                               if not isinstance(p, str) or p in read])
        loaded["_steps"] = rows
        return rows

    def _entities_absorbed(self, ids: list[str], written: dict[str, dict]) -> bool | None:
        """Bring the loaded entity registry and entity vectors up to date with the entities a
        remembered moment added or changed (the columns the writer wrote, `written`, over the row
        loaded; else read by id: primary-key lookups), rather than reading
        every entity again (23,299 at 1,000 h, each call after a remember). Both stay ordered by
        id, as `_tool_entities` and `_tool_vectors_entity` return them; an entity's vector is
        written when it is added, never changed. Returns whether the words the keyword indexes
        read changed (an entity added, or its name, kind, category or status changed); None where
        nothing was loaded (or a row is missing): the next use reads them whole."""
        loaded = self.__dict__
        if "entities" not in loaded:
            return None
        entities = loaded["entities"]
        columns = next(iter(entities.values()), None)
        rows = []
        for i in sorted(set(ids)):
            w, old = written.get(i), entities.get(i)
            if w is not None and old is not None and "emb" not in w:  # changed: the columns set over the row
                rows.append([{**old, **{k: v for k, v in w.items() if k in old}, "emb": None}])
            elif w is not None and old is None and columns is not None and set(columns) <= set(w):  # added
                rows.append([{**{k: w[k] for k in columns}, "emb": w["emb"]}])
            else:
                rows.append(self.store.fetch("_tool_entity_row", participant=self.participant, id=i))
        if not all(rows):
            return None
        table = loaded.get("_vector_cache", {}).get("entity")
        for n, (row,) in enumerate(rows):  # an entity active again whose vector is not loaded: read it
            if row["emb"] is None and row["status"] == "active" and table is not None and row["id"] not in table.index:
                got = self.store.fetch("_tool_entity_row", participant=self.participant, id=row["id"])
                if not got:
                    return None
                rows[n] = got
        grew, words, embs, gone = False, False, {}, set()
        for (row,) in rows:
            emb = row.pop("emb")
            old = entities.get(row["id"])
            if old is None:
                grew = True
            if old is None or any(old[k] != row[k] for k in ("name", "kind", "category", "status")):
                words = True
            entities[row["id"]] = row
            if row["status"] == "active" and emb is not None:
                embs[row["id"]] = emb
            elif row["status"] != "active":
                gone.add(row["id"])
        if grew:  # new ids: in their place among the others
            loaded["entities"] = dict(sorted(entities.items()))
        if table is not None:
            new = [i for i in embs if i not in table.index]
            dropped = any(i in table.index for i in gone)
            if new and not dropped and table.ids:  # added only: their rows inserted in id order (one copy of
                new.sort()           # the matrix, 23,299 rows at 1,000 h, where the general case makes three)
                at = [bisect.bisect_left(table.ids, i) for i in new]
                mat = np.insert(np.asarray(table.mat), at,
                                VectorTable(new, np.asarray([embs[i] for i in new], dtype=np.float32)).mat, axis=0)
                every = list(table.ids)
                for i in reversed(new):  # ids sorted as the rows were inserted (the same positions)
                    every.insert(bisect.bisect_left(every, i), i)
                loaded["_vector_cache"]["entity"] = VectorTable.normalized(every, mat)
            elif new or dropped:
                keep = [i for i in table.ids if i not in gone]
                mats = [np.asarray(table.mat)[np.fromiter((table.index[i] for i in keep), np.int64, len(keep))]] \
                    if keep else []
                if new:  # normalised as a table read whole normalises each row
                    mats.append(VectorTable(new, np.asarray([embs[i] for i in new], dtype=np.float32)).mat)
                every = keep + new
                order = sorted(range(len(every)), key=every.__getitem__)
                mat = np.concatenate(mats)[np.asarray(order, dtype=np.int64)] if every else table.mat[:0]
                loaded["_vector_cache"]["entity"] = VectorTable.normalized([every[k] for k in order], mat)
        return words

    def reload_inferred(self) -> None:
        """Forget the inferred knowledge loaded (routines, preferences, their vectors, keywords and
        links), after a consolidation replaced it: the next call reads the new records."""
        loaded = self.__dict__
        for name in ("routines", "_routine_details", "preferences", "tasks", "_links", "_link_kinds"):
            loaded.pop(name, None)
        for cache in (loaded.get("_vector_cache", {}), loaded.get("_bm25_cache", {})):
            cache.pop("routine", None)
            cache.pop("preference", None)
        self._changed("routine", "preference", rows=("_tool_inferred_links",))

    def freeze_loaded(self) -> None:
        """After `warm`: what was loaded since (the structures a first `ask` or `plan` builds on
        this view, in the layers above) joins the permanent generation too, as warm's loads did;
        `close` gives it back with them. Nothing for a view never warmed. Garbage without a cycle
        is still freed as ever: only the cyclic collector stops walking it."""
        with _FROZEN_LOCK:
            if self.__dict__.get("_frozen"):
                gc.freeze()

    def warm(self) -> None:
        """Load everything the tools read once (what the first call would otherwise pay)."""
        for t in TABLES:
            self.vectors(t)
        _ = self.entities, self.places, self.videos, self.routines, self.preferences, self.graph
        _ = self.history, self._keyed("_tool_segment"), self._keyed("_tool_video_events")
        if self.config.keyword == "bm25":
            for t in TABLES:
                self._bm25(t)
        # What was loaded lives as long as the view: out of the cyclic collector's reach (gc.freeze),
        # a full collection no longer walks it (at 1,000 h, 100-200 ms, paid by whichever call it
        # fell in). `close` gives it back.
        if not self.__dict__.get("_frozen"):
            _freeze()
            self._frozen = True


def _writable(bank: Path) -> bool:
    cache = bank / ".cache"
    return os.access(cache if cache.is_dir() else bank, os.W_OK)


@dataclass
class Persisted:
    written: list[Path] = field(default_factory=list)
    seconds: float = 0.0


def persist_bank(bank_path: str | Path, participants: list[str] | None = None) -> Persisted:
    """Write the persisted tool stores of each participant (all by default) whose files are
    missing or stale (after a build or `memora consolidate`); returns the directories written."""
    t0 = time.perf_counter()
    bank = Bank(bank_path)
    out = Persisted()
    for p in bank.participants() if participants is None else participants:
        with MemoryView.open(bank_path, p, persist=True, keep_loaded=False) as view:
            if view.persisted_written is not None:
                out.written.append(view.persisted_written)
    out.seconds = time.perf_counter() - t0
    return out
