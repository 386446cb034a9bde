"""The wheel carries what the package reads at run time: the schema, the named queries and the
bundled data (mapped from schema/, queries/ and bench/data/), found with importlib.resources once
installed. A real wheel, installed (not editable) into a folder, imported from outside the checkout.
`.ci/wheel-check` goes further: a fresh venv, then build, tool, ask and a bench run."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_wheel_ships_schema_queries_and_data_and_reads_them_installed(tmp_path):
    dist, source = tmp_path / "dist", tmp_path / "source"  # a copy: setuptools writes build/ into the tree it builds
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".git", ".venv", "banks", "runs", "build", "dist", "tests",
                                                                "*.egg-info", "__pycache__", ".pytest_cache", "*.kuzu*"))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    build = subprocess.run([*pip, "wheel", "--quiet", "--no-deps", "--no-build-isolation", "-w", str(dist), str(source)],
                           capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert build.returncode == 0, build.stderr
    wheel = next(dist.glob("memora_graph-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder, inside in (("schema", "schema"), ("queries", "queries"), ("bench/data", "data")):
        for f in (ROOT / folder).rglob("*"):
            if f.is_file():
                assert f"memora_graph/_bundled/{inside}/{f.relative_to(ROOT / folder).as_posix()}" in names, f
    assert not [n for n in names if n.startswith(("notes/", "tests/", "docs/"))]

    site = tmp_path / "site"
    install = subprocess.run([*pip, "install", "--quiet", "--no-deps", "--no-index", "--target", str(site), str(wheel)],
                             capture_output=True, text=True, timeout=600)
    assert install.returncode == 0, install.stderr
    probe = ("import json; from memora_graph import paths; from memora_graph.queries import load_queries; "
             "from memora_graph.schema import schema_tables; "
             "print(json.dumps({'schema': str(paths.SCHEMA_DIR), 'data': str(paths.data_dir()), "
             "'queries': len(load_queries()), 'tables': len(schema_tables()), "
             "'annotations': paths.default_annotations().is_file(), 'tasks': paths.calibration_dir().is_dir()}))")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MEMORA_DATA_DIR")}
    env["PYTHONPATH"] = str(site)
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout)
    assert got["schema"].startswith(str(site)) and got["data"].startswith(str(site))  # the installed copy
    assert got["queries"] == len(list((ROOT / "queries").glob("*.cypher"))) and got["tables"] > 10
    assert got["annotations"] and got["tasks"]
    # the commands ship too: the cli package with its perf benchmarks, runnable as `python -m memora_graph.cli`
    assert {"memora_graph/cli/__main__.py", "memora_graph/cli/perf/tools.py"} <= names
    run = subprocess.run([sys.executable, "-m", "memora_graph.cli", "perf", "tools", "--help"], capture_output=True,
                         text=True, cwd=tmp_path, env=env, timeout=300)
    assert run.returncode == 0 and "Usage: python -m memora_graph.cli perf tools" in run.stdout, run.stderr
    env["MEMORA_DATA_DIR"] = str(tmp_path / "elsewhere")  # still points the data at another copy
    run = subprocess.run([sys.executable, "-c", "from memora_graph import paths; print(paths.epic_dir())"],
                         capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert run.stdout.strip() == str(tmp_path / "elsewhere" / "epic-kitchens-100")
