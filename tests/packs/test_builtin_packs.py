"""Every built-in pack is a test case: it validates, and each of its scenes steps headless deterministically."""

from __future__ import annotations

import pytest

from chainsim.game.packs import pack as packs
from chainsim.game.trainer.headless import run_pack

BUILTIN = sorted((f.name, f.path) for f in packs.discover() if f.source == "builtin")


def _scenes():
    out = []
    for name, path in BUILTIN:
        pack, problems = packs.validate(path, load_meshes=False)
        scenes = pack.scene_names() if pack else []
        for s in scenes or [None]:
            out.append(f"{name}/{s}" if s else name)
    return out


@pytest.mark.parametrize("name,path", BUILTIN, ids=[b[0] for b in BUILTIN])
def test_pack_validates_with_meshes(name, path):
    pack, problems = packs.validate(path)
    assert problems == []
    assert pack.name == name


@pytest.mark.parametrize("ref", _scenes())
def test_scene_steps_headless_and_is_deterministic(ref):
    a = run_pack(ref, 90, events=[])
    b = run_pack(ref, 90, events=[])
    assert a["steps"] == 90
    assert a["digest"] == b["digest"]
