"""The perception-noise model: known errors at known rates, seeded, each logged with its id."""

from __future__ import annotations

import pytest

from memora_graph.errors import DataError
from memora_graph.paths import epic_dir
from memora_graph.perceive.annotations import load_annotations, noun_phrase
from memora_graph.perceive.noise import (
    ERROR_TYPES, NoiseSpec, inject_noise, read_errors, verb_families, write_noisy,
)
from memora_graph.perceive.vocab import VERB_STATE

COLUMNS = ["narration_id", "video_id", "start_s", "stop_s", "narration", "verb_key", "verb_class", "noun_class",
           "all_nouns", "all_noun_classes"]


@pytest.fixture(scope="module")
def p37():
    return load_annotations(participants=["P37"])


@pytest.fixture(scope="module")
def families():
    return verb_families(epic_dir())


def _inject(df, epic_meta, families, spec):
    classes, durations = epic_meta
    return inject_noise(df, classes, spec, durations, families)


def test_the_same_seed_gives_the_same_errors_and_another_seed_others(p37, epic_meta, families):
    a = _inject(p37, epic_meta, families, NoiseSpec.of("mixed", 0.2, seed=3))
    b = _inject(p37, epic_meta, families, NoiseSpec.of("mixed", 0.2, seed=3))
    c = _inject(p37, epic_meta, families, NoiseSpec.of("mixed", 0.2, seed=4))
    assert a.errors == b.errors and a.actions.equals(b.actions)
    assert a.errors != c.errors
    assert len({e["id"] for e in a.errors}) == len(a.errors)  # every error has its own id


@pytest.mark.parametrize("error", ERROR_TYPES)
def test_one_type_at_a_time_hits_about_its_rate_of_its_units_and_nothing_else(p37, epic_meta, families, error):
    res = _inject(p37, epic_meta, families, NoiseSpec.of(error, 0.3))
    counts = res.counts()
    assert all(n == 0 for t, n in counts.items() if t != error)
    assert counts[error] > 0
    if error not in ("alias",):  # alias logs every renamed mention of an aliased object
        assert 0.15 <= counts[error] / res.units[error] <= 0.45, (counts, res.units)


def test_rate_zero_changes_nothing_and_the_written_folder_reads_back_the_same(p37, epic_meta, families, tmp_path):
    spec = NoiseSpec.of("mixed", 0.0)
    res = _inject(p37, epic_meta, families, spec)
    assert res.errors == []
    path = write_noisy(tmp_path / "clean", res, epic_dir(), spec)
    back = load_annotations(path)
    rounded = lambda df: df.select(COLUMNS).with_columns(df["start_s"].round(6), df["stop_s"].round(6))  # noqa: E731
    assert rounded(back).equals(rounded(p37))  # times to the microsecond: a timestamp's float may differ in the last bit
    assert read_errors(tmp_path / "clean") == []


def test_each_error_is_what_its_type_says(p37, epic_meta, families, tmp_path):
    classes, durations = epic_meta
    spec = NoiseSpec.of("mixed", 0.3, delta=4.0, seed=1)
    res = _inject(p37, epic_meta, families, spec)
    by_type = {t: [e for e in res.errors if e["type"] == t] for t in ERROR_TYPES}
    rows = {r["narration_id"]: r for r in res.actions.iter_rows(named=True)}
    names = {v: k for k, v in classes.nouns.items()}
    for e in by_type["swap"]:  # a confusable noun: the same EPIC category
        assert classes.noun_category[e["true_class"]] == classes.noun_category[e["swap_class"]]
        assert e["true_class"] != e["swap_class"]
    for e in by_type["verb"]:  # a verb of the same family
        assert families[e["verb_class"]] == families[e["new_class"]]
    for e in by_type["state"]:  # the state change is gone: reported as 'use'
        assert e["before"] == VERB_STATE[e["verb"]]
        if e["narration_id"] in rows and not any(x["type"] == "verb" and x["narration_id"] == e["narration_id"]
                                                 for x in res.errors):
            assert rows[e["narration_id"]]["verb_key"] == "use"
    for e in by_type["time"]:
        assert abs(e["shift"]) <= 4.0
        assert 0 <= e["after"] <= durations[e["video"]]
    for e in by_type["segment"]:  # every action of the window is gone
        assert all(a not in rows for a in e["actions"])
    aliased = {}
    for e in by_type["alias"]:  # one object, one second name for the rest of its video
        aliased.setdefault((e["video"], e["true_class"]), set()).add(e["alias_class"])
    assert aliased and all(len(v) == 1 for v in aliased.values())
    for e in by_type["drop"]:
        if e["narration_id"] in rows:
            assert e["noun_class"] not in rows[e["narration_id"]]["all_noun_classes"] or \
                rows[e["narration_id"]]["all_noun_classes"].count(e["noun_class"]) < \
                p37.filter(p37["narration_id"] == e["narration_id"])["all_noun_classes"][0].to_list().count(e["noun_class"])
    # the narration says what the perceiver reported: a swapped noun's new name is in it
    said = [e for e in by_type["swap"] if e["narration_id"] in rows]
    hits = sum(noun_phrase(e["after"]).split()[-1] in rows[e["narration_id"]]["narration"] for e in said)
    assert hits >= 0.8 * len(said)
    assert names  # the class tables were read
    # the folder builds: it reads back with the same rows, and its log is the errors
    path = write_noisy(tmp_path / "noisy", res, epic_dir(), spec)
    back = load_annotations(path)
    assert back.height == res.actions.height
    assert read_errors(tmp_path / "noisy") == res.errors


def test_a_rate_outside_zero_to_one_or_an_unknown_type_is_refused_by_name():
    with pytest.raises(DataError, match="'swap' must lie between 0 and 1"):
        NoiseSpec({"swap": 1.5})
    with pytest.raises(DataError, match="unknown error type 'blur'"):
        NoiseSpec({"blur": 0.1})


@pytest.fixture(scope="module")
def p01():
    return load_annotations(participants=["P01"])


@pytest.mark.parametrize("error", ERROR_TYPES)
def test_measuring_a_perceiver_against_annotations_recovers_the_injected_rate(p01, epic_meta, families, error):
    from memora_graph.perceive.noise import measure_errors

    classes, _ = epic_meta
    res = _inject(p01, epic_meta, families, NoiseSpec.of(error, 0.2, seed=5))
    got = measure_errors(p01, res.actions.drop("_changed"), classes)
    if error == "alias":  # measured per object of a video
        injected = len({(e["video"], e["true_class"]) for e in res.errors}) / res.units["alias"]
    else:
        injected = res.counts()[error] / res.units[error]
    assert got[error]["rate"] == pytest.approx(injected, abs=0.06), (got, injected)
    others = [t for t in ERROR_TYPES if t not in (error, "segment", "drop")]  # a lost action can empty a window
    assert all(got[t]["rate"] <= 0.02 for t in others), got
    clean = measure_errors(p01, p01, classes)
    assert all(v["rate"] == 0 for v in clean.values())


def test_the_perceiver_errors_command_reads_a_noisy_folder_against_the_annotations(p37, epic_meta, families, tmp_path):
    import json as _json

    from click.testing import CliRunner

    from memora_graph.cli.bench import bench_group
    from memora_graph.paths import default_annotations

    spec = NoiseSpec.of("state", 0.5, seed=2)
    res = _inject(p37, epic_meta, families, spec)
    path = write_noisy(tmp_path / "noisy", res, epic_dir(), spec)
    out = CliRunner().invoke(bench_group, ["perceiver-errors", str(default_annotations()), str(path), "--json"])
    assert out.exit_code == 0, out.output
    rows = {r["error"]: r for r in _json.loads(out.output)}
    assert rows["state"]["errors"] == res.counts()["state"] and rows["swap"]["errors"] == 0
