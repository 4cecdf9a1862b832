"""`chainsim bench docs` runs end to end on a small window and reports every page of the pack and
the key page, with what opening one and keeping it open cost."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_bench_docs_reports_each_page(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "game", "bench", "docs", "--out", str(tmp_path), "--frames", "2", "--warmup", "0"]
        + ["--size", "640x400", "--pack", "chainmail-demo"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp_path / "results.json").read_text())
    assert [p["page"] for p in res["pages"]] == ["keys", "about"]
    for p in res["pages"]:
        assert p["lines"] > 5 and p["quads"] > 100  # a page of text was laid out and drawn
        assert p["open_layout_ms"] > 0 and p["build_ms"] > 0 and p["frame_open_ms"] > 0
    assert "| about |" in (tmp_path / "results.md").read_text()
