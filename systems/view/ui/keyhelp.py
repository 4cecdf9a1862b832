"""The key overlay (F1) as a Markdown page: the mouse, the window keys, the procedure's own keys
(HudState.key_rows) and every widget's shortcut, in one table, so what the overlay says is what the
keys do (it is built from the same layout and procedure that handle them)."""

from __future__ import annotations

TITLE = "Keys and mouse"
NAME = "keys"  # the HudState.doc_name that shows this page
ASK = " (asks first if the attempt is not saved)"


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|")


def keys_markdown(widgets: list[dict], key_rows: list[tuple[str, str]], docs: list[str] | None = None) -> str:
    """The page: one table of keys and mouse actions; then, when the pack has help pages (their
    titles in `docs`), how to reach them."""
    saves = any(w["name"] == "sign_in" for w in widgets)  # a trainer that saves attempts (as the window decides)
    rows = [
        ("left-drag in a 3-D view", "turn the view"),
        ("right- or middle-drag", "pan the view"),
        ("wheel", "zoom the view; over a dial or slider: step it; over a page: scroll"),
        ("click", "use a button or toggle; on a surface: pick that point (a marked point, a grip, a cut point)"),
    ]
    rows += list(key_rows)
    for w in widgets:
        if w.get("key"):
            what = w.get("label") or w["name"]
            if w.get("help"):
                what += f": {w['help']}"
            rows.append((f"`{w['key']}`", what))
    rows += [
        ("`F1`", "open or close this page"),
        ("`PageUp` / `PageDown`", "scroll an open page"),
        ("`Esc`", "close the open page; with none open, quit" + (ASK if saves else "")),
        ("`F12`", "save a screenshot in the current folder"),
    ]
    lines = [f"# {TITLE}", "", "| Keys or mouse | What it does |", "|---|---|"]
    lines += [f"| {_cell(k)} | {_cell(v)} |" for k, v in rows]
    if docs:
        button = " (or the **Help** button)" if any(w["name"] == "help" for w in widgets) else ""
        lines += ["", "## Help pages", "", f"**Help pages >** below{button} opens them:", ""]
        lines += [f"- {t}" for t in docs]
    return "\n".join(lines) + "\n"
