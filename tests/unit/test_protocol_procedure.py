"""A study protocol runs only on a pack whose procedure declares the study the study screens run: a protocol
naming the cutting trainer's pack is refused in one line before any trial, and nothing is saved."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.mark.parametrize("mode", [["--scripted"], ["--participant", "p1"]])
def test_a_protocol_on_a_pack_whose_procedure_has_no_study_is_refused_in_one_line(cli, tmp_path, mode):
    proto = tmp_path / "cutting-study.toml"
    proto.write_text(
        'format = 1\npack = "cutting"\n\n[[trial]]\nname = "t1"\nrepeat = 1\ntask = "location"\n'
        'condition = "none"\nscripts = ["scripts/open.toml"]\n'
    )
    db = tmp_path / "records.sqlite3"
    code, _out, err = cli("protocol", proto, *mode, "--db", db)
    assert code == 2
    line = err.strip()
    assert "\n" not in line and "Traceback" not in line
    assert "pack 'cutting' runs the cutting procedure, which declares no study" in line
    assert not Path(db).exists()  # refused before any trial or record


def test_the_shipped_protocol_passes_the_check(cli, tmp_path):
    from types import SimpleNamespace

    from chainsim.assets import ASSETS_DIR
    from chainsim.game.cli.commands.protocol import check_study
    from chainsim.game.study.protocol import load_protocol

    proto = load_protocol(ASSETS_DIR / "prp" / "protocols" / "table61.toml")
    check_study(SimpleNamespace(pack_path=[]), proto)  # the prp pack runs the needle procedure and its study
