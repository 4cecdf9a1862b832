"""User-facing errors: raised anywhere, printed as one line at the CLI edge with exit code 2."""


class UserError(Exception):
    """A problem the user can fix (bad flag, bad file, bad field); the message names it."""

    exit_code = 2
