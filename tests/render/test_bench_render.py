"""`chainsim bench render` runs end to end on a tiny case and writes its three outputs."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_bench_render_writes_table_json_and_plot(tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "game",
            "bench",
            "render",
            "--out",
            str(tmp_path),
            "--triangles",
            "200",
            "3000",
            "--frames",
            "2",
            "--warmup",
            "0",
            "--size",
            "96x64",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    data = json.loads((tmp_path / "results.json").read_text())
    assert [(row["mode"]) for row in data["rows"]] == ["static", "full", "patch"] * 2
    from chainsim.tools.bench.render import sheet

    assert sorted({row["triangles"] for row in data["rows"]}) == [len(sheet(200)[1]), len(sheet(3000)[1])]
    assert abs(len(sheet(3000)[1]) - 3000) < 0.1 * 3000
    assert all(row["median_ms"] > 0 for row in data["rows"])
    patch = [row for row in data["rows"] if row["mode"] == "patch"]
    full = [row for row in data["rows"] if row["mode"] == "full"]
    assert all(p["moved_vertices"] < f["moved_vertices"] for p, f in zip(patch, full))
    assert (tmp_path / "results.md").read_text().count("\n| ") == 7  # header + 6 rows
    # the full rows split their upload; the parts never add up to more than the upload
    for f in full:
        split = f["upload_split_ms"]
        assert set(split) == {"convert", "normals", "write", "gpu_pass", "bookkeeping"}
        assert f["normals_on"] == "cpu"  # sheets this small stay under GPU_NORMALS_MIN
        assert sum(v for k, v in split.items() if k != "bookkeeping") <= f["upload_median_ms"] * 1.5 + 0.5
    assert (tmp_path / "bench-render.png").stat().st_size > 1000
    assert "triangles" in r.stderr  # progress goes to stderr


def test_bench_render_refuses_bad_arguments(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "game", "bench", "render", "--out", str(tmp_path), "--patch", "2"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 2
    assert "--patch" in r.stderr and "Traceback" not in r.stderr
