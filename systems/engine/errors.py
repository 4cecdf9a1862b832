"""User-facing errors: raised anywhere, printed as one line at the CLI edge with exit code 2; and
`Interrupted`, a Ctrl-C a job stopped at cleanly, printed as one line with exit code 130.

Messages quote what the user gave (names, paths, keys); `printable` shows any control, format or
other invisible character in them as an escape, so a message stays one line and cannot be made to
display as something else (a newline in a key, a right-to-left override in a name, a terminal
escape sequence in a file name).
"""

import unicodedata

# control (Cc), format (Cf: bidi overrides, zero-width marks), surrogate, private use, unassigned,
# line and paragraph separators
HIDDEN_CATEGORIES = frozenset({"Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"})


def printable(text: str) -> str:
    """`text` with every hidden or control character shown as a \\uXXXX escape."""
    if text.isprintable():
        return text
    return "".join(c if unicodedata.category(c) not in HIDDEN_CATEGORIES else f"\\u{ord(c):04x}" for c in text)


class UserError(Exception):
    """A problem the user can fix (bad flag, bad file, bad field); the message names it."""

    exit_code = 2

    def lines(self) -> list[str]:
        """What to print: the message as one line, hidden characters escaped."""
        return [printable(str(self))]


class Interrupted(KeyboardInterrupt):
    """Ctrl-C that a job stopped at cleanly; the message says where it stopped and what it kept.

    A KeyboardInterrupt, so nothing that catches Exception on the way out swallows it; the command
    line prints the message as one line and exits 130 (128 + SIGINT), as a shell does."""
