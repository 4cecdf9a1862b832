"""Material presets: a pack names a calibrated preset; explicit keys win; unknown names are one clear line."""

from __future__ import annotations

from chainsim.game.packs import pack as packs


def _pack(tmp_path, material: str):
    root = tmp_path / "p"
    root.mkdir()
    (root / "pack.toml").write_text('[pack]\nname = "p"\nformat = 1\n[materials.tissue]\n' + material)
    return root


def test_preset_fills_unset_chainmail_keys(tmp_path):
    presets = packs.material_presets()
    assert "soft-tissue" in presets
    pack, problems = packs.validate(_pack(tmp_path, 'preset = "soft-tissue"\nbeta = 0.5\n'))
    assert problems == []
    m = pack.section("materials")["tissue"]
    assert m["alpha_min"] == presets["soft-tissue"]["alpha_min"]
    assert m["alpha_max"] == presets["soft-tissue"]["alpha_max"]
    assert m["relax"] == presets["soft-tissue"]["relax_iterations"]
    assert m["beta"] == 0.5  # given explicitly: the preset does not override it


def test_unknown_preset_is_reported(tmp_path):
    pack, problems = packs.validate(_pack(tmp_path, 'preset = "granite"\n'))
    assert pack is None and len(problems) == 1
    assert problems[0].key == "materials.tissue.preset" and "unknown preset 'granite'" in problems[0].message
