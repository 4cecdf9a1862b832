"""`chainsim warmup` compiles (or loads) every kernel ahead and says when they are ready; afterwards
no built-in pack, played with its scripts and drawn as the window draws it, needs a kernel compiled
for an argument type warmup did not compile (the first forceps grip once waited 13.8 s on that)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from chainsim.game.cli.main import main

ROOT = Path(__file__).resolve().parents[2]


def test_warmup_command_readies_the_kernels(capsys):
    assert main(["-q", "warmup"]) == 0
    assert "kernels ready" in capsys.readouterr().out


def _signatures() -> dict[str, set[str]]:
    from numba.core.registry import CPUDispatcher

    out = {}
    for mod in list(sys.modules.values()):
        if getattr(mod, "__name__", "").startswith("chainsim"):
            for v in list(vars(mod).values()):
                if isinstance(v, CPUDispatcher):
                    out[f"{v.py_func.__module__}.{v.__name__}"] = {str(s) for s in v.signatures}
    return out


@pytest.mark.parametrize("pack", ["cutting", "prp"])
def test_no_pack_needs_a_kernel_type_warmup_left_out(pack, monkeypatch):
    monkeypatch.setenv("PYGLET_HEADLESS", "true")
    from chainsim.components.resources import PendingInput
    from chainsim.game.app.headless import build_app
    from chainsim.game.app.inputscript import load_script
    from chainsim.game.gl.context import GLUnavailable
    from chainsim.game.gl.render_system import draw

    main(["-q", "warmup"])
    before = _signatures()  # what warmup readied; anything else a run needs would compile mid-session
    for script in sorted((ROOT / "assets" / pack / "scripts").glob("*.toml"))[:2]:
        try:
            app = build_app(str(ROOT / "assets" / pack), render=True, headless=True, size=(640, 400))
        except GLUnavailable as e:
            pytest.skip(f"no EGL OpenGL 3.3 context: {e}")
        events = load_script(script)
        app.resource(PendingInput).extend(events)
        last = max(t for t, _ in events) + 0.2
        try:
            n = 0
            while app.time.sim_time < last:
                app.update(app.time.dt)
                n += 1
                if n % 15 == 0:
                    draw(app)
        finally:
            app.close()
        after = _signatures()
        missing = {k: v - before.get(k, set()) for k, v in after.items() if v - before.get(k, set())}
        assert not missing, f"{pack} {script.name} compiled during play: {missing}"
