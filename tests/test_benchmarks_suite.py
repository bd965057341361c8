"""The benchmark suite: one runner lists every case, one schema for every result, the README's
tables regenerate from the committed results, and benchmarks/results stays small and cited.

Fast: nothing here runs a benchmark except one level-0 anatomy case (about 2 s)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from benchmarks import _common, _registry, _tables  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"
PICTURES = (".png", ".gif", ".jpg", ".jpeg")


def _runner(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    run_env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    run_env.pop("FACEWARP_BENCH_RESULTS", None)
    run_env.update(env or {})
    return subprocess.run([sys.executable, "-m", "benchmarks", *args], cwd=REPO, capture_output=True, text=True,
                          env=run_env, timeout=300)


def test_list_shows_every_script_with_a_description():
    scripts = sorted(p.stem for p in (REPO / "benchmarks").glob("*.py") if not p.name.startswith("_"))
    r = _runner("--list")
    assert r.returncode == 0, r.stderr
    listed = [line.split()[0] for line in r.stdout.splitlines() if line.strip()]
    assert listed == scripts, (listed, scripts)
    for line in r.stdout.splitlines():
        name, _, description = line.partition(" ")
        assert description.strip() and not description.strip().startswith("(no description"), line


@pytest.mark.parametrize("name", sorted(_registry.cases()))
def test_every_case_has_main_and_imports_only_shared_helpers(name):
    case = _registry.cases()[name]
    assert case.has_main, f"benchmarks/{name}.py: define main(argv=None) so the runner can call it"
    source = case.path.read_text()
    for other in re.findall(r"^\s*from benchmarks\.(\w+) import|^\s*import benchmarks\.(\w+)", source, re.M):
        mod = next(m for m in other if m)
        assert mod.startswith("_"), f"benchmarks/{name}.py imports benchmarks.{mod}: move shared code to _common/_ict"
    # public API only: tests/test_public_api.py checks benchmarks/ for the private package


def test_unknown_case_is_one_line_exit_2():
    r = _runner("no_such_benchmark")
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "no_such_benchmark" in r.stderr, r.stderr


def test_schema_writer_fields(tmp_path):
    figures = {"fps": np.float32(12.5), "counts": np.arange(3), "name": "x", "path": tmp_path}
    path = _common.save("unit_case", figures, device="cpu", folder=tmp_path)
    doc = json.loads(path.read_text())
    assert list(doc) == list(_common.SCHEMA_KEYS)
    assert doc["benchmark"] == "test_benchmarks_suite"  # the calling module's file name
    assert {"cpu", "cores", "memory_gib"} <= set(doc["machine"]) and doc["machine"]["cores"] >= 1
    assert doc["device"] == "cpu"
    assert {"python", "facewarp", "warp", "numpy"} <= set(doc["versions"]), doc["versions"]
    assert re.match(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00$", doc["date"]), doc["date"]
    assert isinstance(doc["command"], str) and doc["command"].startswith("python -m benchmarks")
    assert doc["figures"] == {"fps": 12.5, "counts": [0, 1, 2], "name": "x", "path": str(tmp_path)}
    assert _common.load(path)["figures"]["counts"] == [0, 1, 2]
    with pytest.raises(ValueError):  # NaN is not JSON: refused, and the old file stays
        _common.save("unit_case", {"fps": float("nan")}, folder=tmp_path)
    assert json.loads(path.read_text())["figures"]["fps"] == 12.5
    with pytest.raises(KeyError, match="missing"):
        bad = tmp_path / "old.json"
        bad.write_text(json.dumps({"machine": {}, "rows": []}))
        _common.load(bad)


@pytest.mark.slow
def test_runner_runs_a_case_into_the_schema(tmp_path):
    r = _runner("--results", str(tmp_path), "anatomy_levels", "--levels", "0")
    assert r.returncode == 0, r.stdout + r.stderr
    doc = _common.load(tmp_path / "anatomy_levels.json")
    assert doc["benchmark"] == "anatomy_levels"
    assert doc["command"] == "python -m benchmarks anatomy_levels --levels 0"
    row = doc["figures"]["levels"][0]
    assert row["level"] == 0 and row["tets"] > 1000 and row["inverted"] == 0
    assert not (RESULTS / ".anatomy_levels.json.tmp").exists()


def test_committed_results_use_the_schema():
    known = set(_registry.cases())
    for path in sorted(RESULTS.rglob("*.json")):
        if path == RESULTS / "demo" / "report.json":  # the demo's own report, shown as it writes it
            continue
        doc = json.loads(path.read_text())
        assert list(doc)[:len(_common.SCHEMA_KEYS)] == list(_common.SCHEMA_KEYS), path
        assert doc["benchmark"] in known, (path, doc["benchmark"])


def _pages_text() -> str:
    return "\n".join(p.read_text() for p in _tables.documents())


def test_readme_tables_are_up_to_date():
    names = re.findall(r"<!-- table:([a-z0-9_]+) -->", _pages_text())
    assert {"preset_targets", "physics_levels", "measured"} <= set(names), names
    assert _tables.stale() == [], "run: python -m benchmarks --tables"


def test_readme_tables_notice_a_changed_result(tmp_path):
    """The check can fail: a changed figure in a result makes its table stale."""
    shutil.copytree(RESULTS, tmp_path / "results")
    path = tmp_path / "results" / "physics_steps_cuda.json"
    doc = json.loads(path.read_text())
    doc["figures"]["levels"][0]["implicit"]["frames_per_second"] = 123.0
    path.write_text(json.dumps(doc))
    stale = _tables.stale(None, _tables.Results(tmp_path / "results"))
    assert sorted(stale) == ["measured", "physics_levels"], stale
    assert "**123 frames/s**" in _tables.render("physics_levels", _tables.Results(tmp_path / "results"))


def test_results_are_small_and_cited():
    files = [p for p in RESULTS.rglob("*") if p.is_file() and not p.name.startswith(".")]
    total = sum(p.stat().st_size for p in files)
    assert total < 8 * 2**20, f"benchmarks/results holds {total / 2**20:.1f} MB (limit 8 MB)"
    for p in files:
        if p.suffix.lower() in PICTURES:
            assert p.stat().st_size < 300 * 2**10, f"{p.relative_to(REPO)}: {p.stat().st_size >> 10} KB (limit 300 KB)"
    readme = _pages_text()
    reports = "".join(p.read_text() for p in RESULTS.rglob("*.md"))
    globs = [g for g in re.findall(r"`([\w./-]*\*[\w./-]*)`", readme)]
    used = _tables.Results()
    for name in _tables.TABLES:
        _tables.render(name, used)
    read_by_tables = {f"{n}.json" for n in used._docs}
    for p in files:
        rel = p.relative_to(RESULTS).as_posix()
        cited = (rel in readme or p.name in readme or rel in reports or p.name in reports
                 or any(Path(rel).match(g) for g in globs) or rel in read_by_tables
                 or (p.suffix == ".json" and p.with_suffix(".md").name in readme))  # the data behind a cited report
        assert cited, (f"benchmarks/results/{rel} is not cited by README.md or a docs page (nor by a report or table it cites): "
                       "delete it (regenerate with python -m benchmarks NAME) or cite it")
