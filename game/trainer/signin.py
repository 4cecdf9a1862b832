"""Signing in at the window: class and trainee typed into a form shown in the page box, remembered
for the next start, and the line that says who is signed in and where the records are kept.

The thesis' assessment tool files attempts under a class and a user name (3.3.4, Fig. 3.11); a
trainee who starts `chainsim play prp` without --class/--trainee is asked here instead of being
saved as "anonymous". The form lives in the window layer (typing is not simulation input, so it is
neither recorded nor able to press the keys of the controller); what it decides goes into the App's
Settings, where the assessment reads it when saving.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import platformdirs

from chainsim.game.records.validate import clean_name
from chainsim.systems.engine import atomicfile, datafile
from chainsim.systems.engine.errors import UserError

logger = logging.getLogger(__name__)

FIELDS = (("class", "Class"), ("trainee", "Your name"))


def remembered_path() -> Path:
    """<user config dir>/chainsim/signin.json ($XDG_CONFIG_HOME is honoured on Linux)."""

    return Path(platformdirs.user_config_dir("chainsim")) / "signin.json"


def remembered() -> dict[str, str]:
    """The class and trainee of the last sign-in, or empty strings (also for a damaged file or a name
    the records would refuse, e.g. one holding a right-to-left override)."""
    try:
        data = datafile.load(remembered_path(), max_bytes=64 * 1024, what="sign-in file")
    except UserError:
        data = {}
    out = {}
    for k, _ in FIELDS:
        v = data.get(k, "") if isinstance(data, dict) else ""
        try:
            out[k] = clean_name(k, v) if v else ""
        except UserError:
            out[k] = ""
    return out


def remember(values: dict[str, str]) -> None:
    path = remembered_path()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomicfile.write_text(path, json.dumps({k: values[k] for k, _ in FIELDS}))
    except OSError as e:  # not remembering is no reason to stop
        logger.warning("could not remember the sign-in in %s: %s", path, e.strerror)


def status_line(settings: dict, records_path) -> str:
    who = settings.get("trainee") or "nobody (attempts go to anonymous)"
    cls = settings.get("class") or "default"
    return f"Signed in: {who}, class {cls}. Records: {records_path}"


class SignInForm:
    """Text fields (class, name; and a password when saving to a records server the trainee has no
    token for); `text` types, `key` handles tab / backspace / return; `done` when accepted.

    `login(name, password)` signs in to the server (chainsim.game.records.remote.login) and raises
    UserError when the server refuses; the password is never shown, stored or remembered.
    """

    def __init__(self, values: dict[str, str], records_path, login=None):
        self.fields = FIELDS + ((("password", "Password"),) if login is not None else ())
        self.values = {k: str(values.get(k) or "") for k, _ in self.fields}
        self.focus = "class" if not self.values["class"] else "trainee"
        self.records_path = records_path
        self.login = login
        self.error = ""
        self.done = False

    def text(self, typed: str) -> None:
        typed = "".join(ch for ch in typed if ch.isprintable())
        if typed:
            self.values[self.focus] = (self.values[self.focus] + typed)[: 256 if self.focus == "password" else 64]
            self.error = ""

    def key(self, name: str) -> None:
        if name == "tab":
            keys = [k for k, _ in self.fields]
            self.focus = keys[(keys.index(self.focus) + 1) % len(keys)]
        elif name == "backspace":
            self.values[self.focus] = self.values[self.focus][:-1]
        elif name in ("return", "enter"):
            self.submit()

    def submit(self) -> None:
        try:
            for k, label in FIELDS:
                self.values[k] = clean_name(label.lower(), self.values[k])
        except UserError as e:
            self.error = str(e)
            for k, _ in FIELDS:
                if not self.values[k].strip():
                    self.focus = k
                    break
            return
        if self.login is not None:
            try:
                self.login(self.values["trainee"], self.values["password"])
            except UserError as e:
                self.error = str(e)
                self.values["password"] = ""
                self.focus = "password"
                return
            self.values["password"] = ""  # not kept once the server has given its token
        self.done = True

    def markdown(self) -> str:
        rows = []
        for k, label in self.fields:
            v = "*" * len(self.values[k]) if k == "password" else self.values[k].replace("|", "\\|")
            cursor = "_" if self.focus == k else ""
            # an empty field says so (an empty code span would show its two backticks)
            shown = f"`{v}{cursor}`" if v or cursor else "*(empty)*"
            rows.append(f"| {'**' + label + '**' if self.focus == k else label} | {shown} |")
        out = [
            "# Sign in",
            "",
            "Your attempts are saved under your class and name, so you and your trainer can find them.",
            "",
            "| Field | Typed |",
            "|---|---|",
            *rows,
            "",
            "Type, **Tab** moves to the other field, **Backspace** deletes, **Enter** signs in. "
            "The names are remembered for the next start. **Esc** closes this page without signing in "
            "(attempts then go to anonymous; **Sign in** opens it again).",
            "",
            f"Records are kept in `{self.records_path}`.",
        ]
        if self.login is not None:
            out[2] = "Your attempts are saved on your programme's records server under your account: sign in once."
        if self.error:
            out += ["", f"**Not yet:** {self.error}"]
        return "\n".join(out) + "\n"
