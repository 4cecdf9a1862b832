"""A needle pack that validates never fails a trainee: each case of issue 26 is one validate line naming
its key, and a message that validates can always be formatted with what its event gives."""

from __future__ import annotations

import shutil
import string

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.game.trainer.headless import validate_pack
from chainsim.systems.procedures.needle import checks
from chainsim.systems.procedures.needle.handles import _Blank
from chainsim.systems.procedures.needle.procedure import DEFAULTS

from .conftest import ROOT

WELL_DONE = 'message = "Well done: the needle tip is at the mental foramen."'


@pytest.fixture
def mental_block(tmp_path):
    root = tmp_path / "mental-block"
    shutil.copytree(ROOT / "assets" / "mental-block", root)

    def edit(old: str, new: str):
        text = (root / "pack.toml").read_text()
        assert old in text, old
        (root / "pack.toml").write_text(text.replace(old, new, 1))
        return validate_pack(root)[1]

    return edit


def _metrics(n: int) -> str:
    return "".join(f'[metrics.extra_{i}]\nlabel = "extra {i}"\nmeasure = "duration"\n' for i in range(n))


CASES = {
    # id -> (old text, new text, key of the one problem, words of its message)
    "bad-format-spec": (WELL_DONE, 'message = "Well done {dist_mm:.1q} mm"', "feedback.0.message", "format code 'q'"),
    "attribute-and-open-brace": (WELL_DONE, 'message = "{patient.name} {"', "feedback.0.message", "formatted"),
    "unknown-field": (WELL_DONE, 'message = "Well done {patient}"', "feedback.0.message", "unknown field '{patient}'"),
    "text-field-as-number": (
        'message = "Landmark 1 placed on the {side} side',
        'message = "Landmark 1 placed on the {side:.2f} side',
        "feedback.4.message",
        "format code 'f'",
    ),
    "metric-step-missing": ('step = "insert"', 'step = "insrt"', "metrics.insert_time_s.step", "'insrt' is not a step"),
    "metric-role-missing": ('role = "bone"', 'role = "bones"', "metrics.bone_contacts.role", "'bones' is not a role"),
    "too-many-metrics": ("[docs.background]", _metrics(209) + "[docs.background]", "metrics", "at most 200"),
    "unknown-aid": (
        'aids = ["skin_transparent"',
        'aids = ["x_ray_goggles", "skin_transparent"',
        "needle_procedure.aids",
        "not an aid",
    ),
    "sides-empty": ('sides = ["left", "right"]', "sides = []", "needle_procedure.sides", "uses {side}"),
    "side-name-field": (
        'opening = "mental_{side}"',
        'opening = "mental_{sde}"',
        "roles.foramen.opening",
        "unknown field",
    ),
    "reset-step-missing": (
        'reset_step = "aim_horizontal"',
        'reset_step = "aim"',
        "needle_procedure.reset_step",
        "not a step",
    ),
    # the debrief formats ideal_path per side when an attempt ends: a bad name must fail here, not there
    "ideal-path-brace": (
        'ideal_path = "mental_{side}"',
        'ideal_path = "mental}_{side}"',
        "needle_procedure.ideal_path",
        "'}'",
    ),
    "ideal-path-field": (
        'ideal_path = "mental_{side}"',
        'ideal_path = "mental_{sid}"',
        "needle_procedure.ideal_path",
        "unknown field",
    ),
    "feedback-event-unknown": ('on = "reset"', 'on = "reste"', "feedback.8.on", "not an event"),
    "step-landmark-missing": ('landmark = "entry"', 'landmark = "entri"', "steps.1.landmark", "not a landmark id"),
    "role-entity-missing": (
        '[entities.mandible.mesh]\nmesh = "mandible"',
        '[entities.jaw.mesh]\nmesh = "mandible"',
        "roles.bone.entities",
        "'mandible' is not an entity",
    ),
    "step-id-for-records": ('id = "review"', 'id = "review step"', "steps.7.id", "step id"),
    "metric-name-for-records": (
        "[metrics.redirections]",
        "[metrics.re-directions]",
        "metrics.re-directions",
        "letters",
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_what_a_run_would_fail_on_is_one_validate_line_naming_the_key(case, mental_block):
    old, new, key, words = CASES[case]
    problems = mental_block(old, new)
    assert problems, "validates, but the run would fail"
    assert problems[0].key == key, [str(p) for p in problems]
    assert words in problems[0].message, str(problems[0])
    assert all("\n" not in str(p) for p in problems)


def test_an_entity_the_needle_can_touch_has_a_name_the_records_store(mental_block):
    mental_block('[entities.mandible.mesh]\nmesh = "mandible"', '[entities.Mandible.mesh]\nmesh = "mandible"')
    problems = mental_block('entities = ["mandible", "skull"]', 'entities = ["Mandible", "skull"]')
    assert [p.key for p in problems] == ["roles.bone.entities"], [str(p) for p in problems]
    assert "lower_snake_case" in problems[0].message


@pytest.mark.parametrize("event, message", sorted(DEFAULTS.items()))
def test_the_built_in_messages_pass_the_check_of_their_event(event, message):
    assert checks.format_problem(message, checks.event_values(event)) == ""


FIELD_TEXT = st.text(alphabet=string.ascii_letters + "{}:.!0123456789[]_ %", max_size=30)


@settings(max_examples=400, deadline=None)
@given(text=FIELD_TEXT, event=st.sampled_from(sorted(checks.MESSAGE_VALUES)))
def test_a_message_that_passes_the_check_formats_with_every_value_its_event_gives(text, event):
    values = checks.event_values(event)
    if checks.format_problem(text, values) == "":
        for v in values:
            assert isinstance(text.format_map(_Blank(v)), str)
        # and with other values of the same types, as a run gives them
        for v in values:
            other = {k: (x * 7 if isinstance(x, (int, float)) else x + " y") for k, x in v.items()}
            text.format_map(_Blank(other))


@settings(max_examples=300, deadline=None)
@given(text=FIELD_TEXT)
def test_a_side_name_that_passes_formats_for_any_side(text):
    if checks.format_problem(text, checks.SIDE_VALUES, strict=True) == "":
        for side in ("left", "right", ""):
            text.format(side=side)


def test_a_panel_without_a_name_is_a_line_not_a_traceback(mental_block):
    problems = mental_block('name = "controller"\nkind = "panel"', 'kind = "panel"')
    assert problems[0].key == "layouts.trainer.viewports.2" and "'name'" in problems[0].message
    assert all("\n" not in str(p) for p in problems)
