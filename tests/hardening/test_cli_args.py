"""Bad flags: every number a flag takes is finite and bounded; one line, exit 2, nothing run or written.

The table covers each command's numeric flags with values a careless user types (negative counts,
huge counts, NaN, inf, 1e300, text) and the examples of the hardening report (`--relax 1e12`
hung, `--relax -2` and `--max-elements -5` were accepted, `-1e3` was taken for a flag).
"""

from __future__ import annotations

import numpy as np
import pytest

from chainsim.systems.engine import meshgen

from .conftest import assert_one_line_error, chainsim

CM = ["--alpha-min", "0.8", "--alpha-max", "1.2", "--beta", "0.1"]

# id -> (argv after `chainsim`, words the error names); MESH and OUT are filled in by the test
CASES: dict[str, tuple[list[str], tuple[str, ...]]] = {
    "chainmail-relax-1e12": (
        ["chainmail", "MESH", "--grab", "0", "--to", "1", "1", *CM, "--relax", "1000000000000", "--out", "OUT"],
        ("--relax", "0 to 1000"),
    ),
    "chainmail-relax-negative": (
        ["chainmail", "MESH", "--grab", "0", "--to", "1", "1", *CM, "--relax", "-2", "--out", "OUT"],
        ("--relax",),
    ),
    "chainmail-to-1e308": (
        ["chainmail", "MESH", "--grab", "0", "--to", "1e308", "0", *CM, "--out", "OUT"],
        ("--to", "1e+06"),
    ),
    "chainmail-to-nan": (
        ["chainmail", "MESH", "--grab", "0", "--to", "nan", "0", *CM, "--out", "OUT"],
        ("--to", "finite"),
    ),
    "chainmail-to-inf": (
        ["chainmail", "MESH", "--grab", "0", "--to", "-inf", "0", *CM, "--out", "OUT"],
        ("--to", "finite"),
    ),
    "chainmail-to-text": (
        ["chainmail", "MESH", "--grab", "0", "--to", "left", "0", *CM, "--out", "OUT"],
        ("--to", "number"),
    ),
    "chainmail-grab-10**23": (
        ["chainmail", "MESH", "--grab", "100000000000000000000000", "--to", "1", "1", *CM, "--out", "OUT"],
        ("--grab",),
    ),
    "chainmail-grab-out-of-mesh": (
        ["chainmail", "MESH", "--grab", "4000", "--to", "1", "1", *CM, "--out", "OUT"],
        ("--grab", "0..15"),
    ),
    "chainmail-alpha-min-5": (
        [
            "chainmail",
            "MESH",
            "--grab",
            "0",
            "--to",
            "1",
            "1",
            "--alpha-min",
            "5",
            "--alpha-max",
            "1.2",
            "--beta",
            "0.1",
            "--out",
            "OUT",
        ],
        ("--alpha-min", "[0, 1]"),
    ),
    "chainmail-alpha-max-1e309": (
        [
            "chainmail",
            "MESH",
            "--grab",
            "0",
            "--to",
            "1",
            "1",
            "--alpha-min",
            "0.8",
            "--alpha-max",
            "1e309",
            "--beta",
            "0.1",
            "--out",
            "OUT",
        ],
        ("--alpha-max", "finite"),
    ),
    "chainmail-beta-negative": (
        [
            "chainmail",
            "MESH",
            "--grab",
            "0",
            "--to",
            "1",
            "1",
            "--alpha-min",
            "0.8",
            "--alpha-max",
            "1.2",
            "--beta",
            "-1",
            "--out",
            "OUT",
        ],
        ("--beta",),
    ),
    "chainmail-relax-step-zero": (
        ["chainmail", "MESH", "--grab", "0", "--to", "1", "1", *CM, "--relax-step", "0", "--out", "OUT"],
        ("--relax-step", "(0, 1]"),
    ),
    "chainmail-out-missing-folder": (
        ["chainmail", "MESH", "--grab", "0", "--to", "1", "1", *CM, "--out", "MISSING/x.npz"],
        ("--out", "does not exist"),
    ),
    "chainmail-out-is-a-folder": (
        ["chainmail", "MESH", "--grab", "0", "--to", "1", "1", *CM, "--out", "DIR.npz"],
        ("--out", "is a folder"),
    ),
    "bench-chainmail-relax-negative": (
        ["bench", "chainmail", "--mesh", "MESH", "--grab", "0", "--to", "1", "1", "--relax", "-2"],
        ("--relax",),
    ),
    "bench-chainmail-max-elements-negative": (["bench", "chainmail", "--max-elements", "-5"], ("--max-elements",)),
    "bench-chainmail-max-elements-1e300": (["bench", "chainmail", "--max-elements", "1e300"], ("--max-elements",)),
    "bench-chainmail-repeat-negative": (["bench", "chainmail", "--repeat", "-1"], ("--repeat",)),
    "bench-chainmail-repeat-huge": (["bench", "chainmail", "--repeat", "10000000000"], ("--repeat", "0 to 1000")),
    "bench-chainmail-to-nan": (
        ["bench", "chainmail", "--mesh", "MESH", "--grab", "0", "--to", "nan", "1"],
        ("--to", "finite"),
    ),
    "bench-render-frames-negative": (["bench", "render", "--frames", "-1"], ("--frames",)),
    "bench-render-triangles-zero": (["bench", "render", "--triangles", "0"], ("--triangles",)),
    "bench-render-patch-2": (["bench", "render", "--patch", "2"], ("--patch",)),
    "run-steps-10**12": (["run", "loop-demo", "--steps", "1000000000000"], ("--steps", "0 to 1000000")),
    "run-steps-negative": (["run", "loop-demo", "--steps", "-1"], ("--steps",)),
    "run-dt-zero": (["run", "loop-demo", "--dt", "0"], ("--dt", "[1e-05, 0.1]")),
    "run-dt-negative": (["run", "loop-demo", "--dt", "-1"], ("--dt",)),
    "run-dt-1e300": (["run", "loop-demo", "--dt", "1e300"], ("--dt",)),
    "run-dt-text": (["run", "loop-demo", "--dt", "fast"], ("--dt", "number")),
    "run-screenshot-every-negative": (["run", "loop-demo", "--screenshot-every", "-1"], ("--screenshot-every",)),
    "run-size-zero": (["run", "loop-demo", "--size", "0x0"], ("--size", "WIDTHxHEIGHT")),
    "run-size-huge": (["run", "loop-demo", "--size", "100000x10"], ("--size",)),
    "run-class-empty": (["run", "loop-demo", "--class", ""], ("--class", "empty")),
    "run-trainee-200-chars": (["run", "loop-demo", "--trainee", "t" * 200], ("--trainee", "at most 64")),
    "run-trainee-rtl-override": (["run", "loop-demo", "--trainee", "eve\u202egnp.exe"], ("--trainee", "U+202E")),
    "run-trainee-zero-width": (["run", "loop-demo", "--trainee", "al\u200bice"], ("--trainee", "U+200B")),
    "run-class-newline": (["run", "loop-demo", "--class", "c1\nc2"], ("--class", "U+000A")),
    "records-show-10**23": (["records", "--db", "DB", "show", "100000000000000000000000"], ("id",)),
    "records-show-zero": (["records", "--db", "DB", "show", "0"], ("id", "from 1")),
    "records-delete-negative": (["records", "--db", "DB", "delete", "-1"], ("id",)),
    "records-show-text": (["records", "--db", "DB", "show", "one"], ("id", "whole number")),
    "play-exit-after-nan": (["play", "loop-demo", "--exit-after", "nan"], ("--exit-after", "finite")),
    "study-block-n-huge": (
        ["study", "calibrate", "--block-n", "1000000000", "--nu", "0.3", "--name", "x"],
        ("--block-n",),
    ),
    "study-nu-nan": (["study", "calibrate", "--nu", "nan", "--name", "x"], ("--nu", "finite")),
    "study-E-negative": (["study", "calibrate", "--nu", "0.3", "--E", "-1", "--name", "x"], ("--E",)),
    "study-pack-steps-negative": (["study", "speed-accuracy", "--out", "OUT", "--pack-steps", "-1"], ("--pack-steps",)),
    "snapshot-steps-negative": (["snapshot", "loop-demo", "--out", "x.png", "--steps", "-1"], ("--steps",)),
    "snapshot-size-zero": (["snapshot", "loop-demo", "--out", "x.png", "--size", "0x5"], ("--size",)),
}


@pytest.fixture
def files(tmp_path):
    pos, links = meshgen.grid((4, 4))
    np.savez(tmp_path / "g.npz", positions=pos, links=links)
    (tmp_path / "DIR.npz").mkdir()
    return {
        "MESH": str(tmp_path / "g.npz"),
        "OUT": str(tmp_path / "out.npz"),
        "DB": str(tmp_path / "r.sqlite3"),
        "DIR.npz": str(tmp_path / "DIR.npz"),
        "MISSING/x.npz": str(tmp_path / "missing" / "x.npz"),
    }


def _argv(args, files):
    return [files.get(a, a) for a in args]


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_flag_is_one_line_and_exit_2(case, cli, files, tmp_path):
    args, words = CASES[case]
    code, out, err = cli(*_argv(args, files))
    assert_one_line_error(code, err, *words)
    assert err.count("\n") == 1, err
    assert not (tmp_path / "out.npz").exists()
    assert not (tmp_path / "r.sqlite3").exists()  # reading records never creates a database


def test_relax_1e12_no_longer_hangs(files):
    r = chainsim(*_argv(CASES["chainmail-relax-1e12"][0], files), timeout=60)
    assert_one_line_error(r.returncode, r.stderr, "--relax")


def test_negative_numbers_in_e_notation_are_values(cli, files, tmp_path):
    code, out, err = cli(
        "chainmail", files["MESH"], "--grab", "5", "--to", "-1e0", "-2.5e-1", *CM, "--out", files["OUT"]
    )
    assert code == 0, err
    with np.load(files["OUT"]) as z:
        np.testing.assert_allclose(z["positions"][5], [-1.0, -0.25])
        assert np.isfinite(z["positions"]).all()


def test_a_far_but_allowed_target_writes_only_finite_numbers(cli, files):
    code, out, err = cli(
        "chainmail",
        files["MESH"],
        "--grab",
        "0",
        "--to",
        "-1e6",
        "1e6",
        "--alpha-min",
        "0",
        "--alpha-max",
        "1e6",
        "--beta",
        "1e6",
        "--relax",
        "3",
        "--out",
        files["OUT"],
    )
    assert code == 0, err
    with np.load(files["OUT"]) as z:
        assert np.isfinite(z["positions"]).all()


def test_docs_limits_prints_the_limits(cli):
    code, out, err = cli("docs", "limits")
    assert code == 0 and "MAX_RELAX" in out and "CHAINSIM_MAX_MESH_MB" in out
