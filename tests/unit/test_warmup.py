"""`chainsim warmup` compiles (or loads) every kernel ahead and says when they are ready."""

from __future__ import annotations

from chainsim.game.cli.main import main


def test_warmup_command_readies_the_kernels(capsys):
    assert main(["-q", "warmup"]) == 0
    assert "kernels ready" in capsys.readouterr().out
