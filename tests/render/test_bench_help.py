"""`chainsim bench --help` and each benchmark's --help print their text (a stray % in a help string
once made argparse crash instead)."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("args", [(), ("chainmail",), ("models",), ("render",), ("window",), ("docs",), ("records",)])
def test_bench_help_prints(cli, args):
    code, out, err = cli("bench", *args, "--help")
    assert code == 0, err
    assert "usage:" in out and "Traceback" not in err
