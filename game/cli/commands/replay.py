"""`chainsim replay FILE`: run a recorded session again and check it reaches the same digest.

A replay has no side effects: it never saves an attempt (a Save pressed in the recording shows
"not saved" instead) and never writes, creates or opens anything the recording names, since a
recording is a file anyone may hand over. Its only output is the optional --out folder the user
names. Every field is checked before the run: dt within [MIN_DT, MAX_DT], steps within MAX_STEPS,
known settings of the right type (docs/limits.md).
"""

from __future__ import annotations

from chainsim.game.trainer.headless import run_pack
from chainsim.game.trainer.inputscript import parse_events, read_file
from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import UserError

NAME = "replay"
HELP = "replay a recorded session and compare its final digest"

#: settings a recording may carry; the records database or server it names is ignored (a replay never saves)
REPLAY_SETTINGS = ("db", "records", "class", "trainee", "model", "fluoro_first")


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    p.add_argument("file", help="recording written by `chainsim run --record` or `chainsim play --record`")
    p.add_argument("--out", metavar="DIR", help="folder for summary.json")
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    return p


def check_recording(data, where: str) -> dict:
    """The fields of a recording, checked; raises UserError naming the first bad one."""
    if not isinstance(data, dict) or data.get("chainsim") != "recording":
        raise UserError(f"{where}: not a chainsim recording (expected the JSON written by --record)")
    for key in ("pack", "scene", "digest"):
        v = data.get(key)
        if not isinstance(v, str) or not v or len(v) > limits.MAX_PATH_LENGTH or "\x00" in v:
            raise UserError(f"{where}: field '{key}' missing or not text")
    try:
        steps = limits.whole(data.get("steps"), 0, limits.MAX_STEPS)
    except limits.LimitError as e:
        raise UserError(f"{where}: field 'steps': {e} (docs/limits.md)") from None
    try:
        dt = limits.number(data.get("dt"), limits.MIN_DT, limits.MAX_DT)
    except limits.LimitError as e:
        raise UserError(f"{where}: field 'dt' (the fixed step in seconds): {e}") from None
    settings = data.get("settings") or {}
    if not isinstance(settings, dict):
        raise UserError(f"{where}: field 'settings' must be a table")
    unknown = sorted(set(settings) - set(REPLAY_SETTINGS))
    if unknown:
        raise UserError(f"{where}: unknown setting {unknown[0]!r} in 'settings'; known: {', '.join(REPLAY_SETTINGS)}")
    for key, value in settings.items():
        if key == "fluoro_first":  # the one switch (play/run --fluoro-first); the rest are names
            if not isinstance(value, bool):
                raise UserError(f"{where}: setting 'fluoro_first' must be true or false, got {type(value).__name__}")
        elif not isinstance(value, str):
            raise UserError(f"{where}: setting {key!r} must be text, got {type(value).__name__}")
    kept = {k: v for k, v in settings.items() if k not in ("db", "records")}
    return {
        "pack": data["pack"],
        "scene": data["scene"],
        "digest": data["digest"],
        "steps": steps,
        "dt": dt,
        "settings": kept,
    }


def run(args) -> int:
    data = read_file(args.file)
    rec = check_recording(data, args.file)
    events = parse_events(data, args.file)
    # `pack` is the reference the recording was made with: a name, PACK/SCENE or a folder path (which may
    # hold slashes of its own); it is resolved as `run` resolves it, and the recorded scene is started
    ref = rec["pack"]
    summary = run_pack(
        ref,
        rec["steps"],
        scene=rec["scene"],
        events=events,
        out=args.out,
        pack_paths=args.pack_path,
        dt=rec["dt"],
        settings=rec["settings"],
        save="a replay never saves attempts",
    )
    same = summary["digest"] == rec["digest"]
    print(
        f"replayed {rec['steps']} steps of {ref} (scene {rec['scene']}): digest {summary['digest'][:16]} "
        + ("matches the recording" if same else f"DIFFERS from the recording ({rec['digest'][:16]})")
    )
    return 0 if same else 1
