"""docs/limits.md is the code's limits, and every whole number a manifest takes is bounded."""

from __future__ import annotations

from pathlib import Path

import pytest

import chainsim.game.packs.declarations  # noqa: F401  (registers the manifest sections)
from chainsim.components.registry import COMPONENTS, SECTIONS, FieldError, convert, load_all
from chainsim.systems import manifest_modules
from chainsim.systems.engine import limits

DOC = Path(__file__).resolve().parents[2] / "docs" / "limits.md"


def test_docs_limits_md_is_generated_from_the_code():
    from chainsim.game.records import plausible

    expected = limits.markdown([plausible.markdown()])
    assert DOC.read_text(encoding="utf-8") == expected, "regenerate: chainsim docs limits > docs/limits.md"


def test_every_limit_is_listed_with_its_value():
    text = DOC.read_text(encoding="utf-8")
    for lim in limits.LIMITS.values():
        assert f"`{lim.name}`" in text
        assert getattr(limits, lim.name) == lim.value


def _fields():
    load_all(manifest_modules())
    for schema in list(SECTIONS.values()) + list(COMPONENTS.values()):
        for f in schema.fields:
            yield schema.name, f
            if f.item is not None:
                for g in f.item.fields:
                    yield f"{schema.name}.{f.name}", g


@pytest.mark.parametrize("where, f", [(w, f) for w, f in _fields() if f.kind in ("int", "int_list")])
def test_every_whole_number_a_manifest_takes_has_an_upper_bound(where, f):
    value = 2**63 - 1
    with pytest.raises(FieldError, match="must be <="):
        convert(f, [value] if f.kind == "int_list" else value)
    top = int(f.max) if f.max is not None else limits.MAX_INT
    assert top <= limits.MAX_INT


@pytest.mark.parametrize(
    "where, f", [(w, f) for w, f in _fields() if f.kind in ("float", "vec2", "vec3", "vec4", "float_list")]
)
def test_every_number_a_manifest_takes_is_finite_and_bounded(where, f):
    n = {"vec2": 2, "vec3": 3, "vec4": 4}.get(f.kind)
    for bad in (float("inf"), float("nan"), 1e300, -1e300):
        value = [bad] * n if n else ([bad] * 3 if f.kind == "float_list" else bad)
        with pytest.raises(FieldError):
            convert(f, value)


def test_counts_that_multiply_run_time_have_their_documented_limits():
    load_all(manifest_modules())
    assert SECTIONS["settings"].field("steps").max == limits.MAX_STEPS
    assert SECTIONS["materials"].field("relax").max == limits.MAX_RELAX
    assert COMPONENTS["deformable"].field("relax").max == limits.MAX_RELAX
    assert COMPONENTS["deformable"].field("depth").max == limits.MAX_BRANCH_DEPTH
    assert SECTIONS["meshes"].field("resolution").max == limits.MAX_RESOLUTION
