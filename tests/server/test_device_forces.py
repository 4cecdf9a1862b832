"""An attempt made with a force-feedback device on the records server: the forces the hand felt are kept as the
simulator measured them (a replay of the recording moves the needle as the hand did, but cannot feel the hand
again), said to be so, and drawn on the attempt page; an attempt made without a device has no force section, and
every figure the replay computes stays the replay's."""

from __future__ import annotations

import re

from conftest import save_scored, upload
from test_dashboard import Browser

from chainsim.game.server.scoring import device_reported

#: a short insertion as the device felt it: (time s, depth mm, force N, events); skin gives at 1.2 s
PROFILE = [[0.02 * k, 0.2 * k, 0.1 * k, 0] for k in range(60)] + [[1.2, 12.0, 0.4, 1], [1.3, 12.5, 0.5, 0]]
DEVICE = {
    "device": "sim:keys.csv",
    "device_peak_force_N": 5.9,
    "puncture_force_N": 5.9,
    "bone_contact_s": 0.25,
    "force_profile": PROFILE,
}


def device_upload() -> dict:
    """prp's correct attempt as the simulator sends it after a device run: its device figures in the details and
    the pack's device metrics."""
    body = upload("correct.toml")
    body["details"] = {**body["details"], **DEVICE}
    body["metrics"] = {**body["metrics"], "device_peak_force_N": 5.9, "puncture_force_N": 5.9, "bone_contact_s": 0.25}
    return body


def test_a_device_attempt_keeps_its_forces_says_they_are_reported_and_draws_them(site):
    honest = upload("correct.toml")
    stored = save_scored(site, "alice", device_upload())
    d = stored["details"]
    assert d["force_profile"] == PROFILE and d["device"] == "sim:keys.csv" and d["bone_contact_s"] == 0.25
    assert set(d["reported_by_device"]) >= {"force_profile", "metrics.device_peak_force_N", "metrics.bone_contact_s"}
    assert stored["metrics"]["device_peak_force_N"] == 5.9
    # the replay's own figures are untouched, and taking the device's is no difference
    assert stored["needle_error_mm"] == honest["needle_error_mm"] and not stored.get("differences")
    b = Browser(site)
    b.sign_in("tina")
    status, page, _ = b.get(f"/attempts/{stored['id']}")
    assert status == 200
    section = re.search(r'<section class="force" id="force".*?</section>', page, re.S).group(0)
    assert "cannot feel the hand again" in section and "62 points" in section
    for against in ("depth", "time"):
        assert f'src="/attempts/{stored["id"]}/plot/force-{against}.svg"' in section and "peak 5.9 N" in section
    assert re.search(r"<td[^>]*>Peak force felt</td>\s*<td class=\"num\">5.9 N</td>", page)
    status, svg, hdrs = b.get(f"/attempts/{stored['id']}/plot/force-depth.svg")
    assert status == 200 and hdrs["Content-Type"].startswith("image/svg+xml")
    assert "needle depth (mm)" in svg and "puncture" in svg
    status, svg, _ = b.get(f"/attempts/{stored['id']}/plot/force-time.svg")
    assert status == 200 and "time (s)" in svg
    # the profile is drawn, not listed as raw data among the details
    assert "Force profile" not in page and "[[" not in page and "Device peak force" not in page
    # another trainee may not see it
    bob = Browser(site)
    bob.sign_in("bob")
    assert bob.get(f"/attempts/{stored['id']}/plot/force-depth.svg")[0] == 403


def test_an_attempt_without_a_device_has_no_force_section_and_no_device_rows(site):
    stored = save_scored(site, "alice", upload("correct.toml"))
    assert "force_profile" not in stored["details"] and "reported_by_device" not in stored["details"]
    b = Browser(site)
    b.sign_in("tina")
    status, page, _ = b.get(f"/attempts/{stored['id']}")
    assert status == 200 and 'id="force"' not in page
    assert "Peak force felt" not in page  # a device metric with no device is no row, not a dash
    status, text, _ = b.get(f"/attempts/{stored['id']}/plot/force-depth.svg")
    assert status == 404 and "without a force-feedback device" in text
    assert b.get(f"/attempts/{stored['id']}/plot/other.svg")[0] == 404


def test_the_replays_figure_wins_and_a_claim_without_a_device_takes_nothing():
    record = {"details": {"bone_contact_s": 0.0}, "metrics": {"device_peak_force_N": None, "needle_error_mm": 0.5}}
    claimed = {"details": dict(DEVICE), "metrics": {"device_peak_force_N": 5.9, "needle_error_mm": -9.0}}
    taken = device_reported(claimed, record, ["device_peak_force_N"])
    assert record["details"]["bone_contact_s"] == 0.0  # the replay had a value: it stays
    assert record["metrics"] == {"device_peak_force_N": 5.9, "needle_error_mm": 0.5}  # only device metrics taken
    assert "bone_contact_s" not in taken and "metrics.needle_error_mm" not in taken
    bare = {"details": {}, "metrics": {"device_peak_force_N": None}}
    no_device = {"details": {k: v for k, v in DEVICE.items() if k != "device"}, "metrics": {"device_peak_force_N": 5.9}}
    assert device_reported(no_device, bare, ["device_peak_force_N"]) == []
    assert bare == {"details": {}, "metrics": {"device_peak_force_N": None}}
