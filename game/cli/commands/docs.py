"""`chainsim docs components|limits|models`: the modder reference, the limits and the models' parameters,
generated from the code.

`components` is every manifest section and component, from the one registry; `limits` is every
limit on user input, from chainsim.systems.engine.limits (the text of docs/limits.md); `models` is every
deformation model's parameters, from their one declaration in chainsim.systems.engine.model_params (the
tables of docs/choosing-a-model.md).
"""

from __future__ import annotations

import numpy as np

import chainsim.game.packs.declarations  # noqa: F401  (importing it registers the manifest sections)
from chainsim.components.registry import COMPONENTS, KINDS, REQUIRED, SECTION_STYLE, SECTIONS, load_all
from chainsim.systems import manifest_modules
from chainsim.systems.engine import limits, model_params

NAME = "docs"
HELP = (
    "print reference documentation (components: every manifest key; limits: every input limit; "
    "models: every deformation model's parameters)"
)


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    p.add_argument("topic", choices=["components", "limits", "models"], help="what to print")
    return p


def _fmt_default(f) -> str:

    if f.default is REQUIRED:
        return "required"
    d = f.default
    if isinstance(d, np.ndarray):
        d = d.tolist()
    if isinstance(d, bool):
        return str(d).lower()
    if isinstance(d, str):
        return f'"{d}"'
    if isinstance(d, float):
        return f"{d:g}"
    return str(d)


def render_reference() -> str:
    load_all(manifest_modules())
    out = [
        "# pack.toml reference (format 1)",
        "",
        "Generated from chainsim's registry: every key below is checked by `chainsim validate`.",
        "",
    ]

    def table(schema, heading):
        out.append(heading)
        out.append("")
        out.append(schema.help)
        out.append("")
        out.append("| key | type | default | units | meaning |")
        out.append("|---|---|---|---|---|")
        for f in schema.fields:
            kind = KINDS[f.kind] + (f" ({', '.join(c for c in f.choices if c)})" if f.choices else "")
            rng = ""
            if f.min is not None or f.max is not None:
                rng = f" Range {'' if f.min is None else f'{f.min:g}'}..{'' if f.max is None else f'{f.max:g}'}."
            out.append(f"| `{f.name}` | {kind} | {_fmt_default(f)} | {f.units} | {f.help}{rng} |")
        out.append("")
        for f in schema.fields:
            if f.item is not None:
                table(f.item, f"#### each entry of `{f.name}`")

    out.append("## Sections")
    out.append("")
    for name, schema in SECTIONS.items():
        style = SECTION_STYLE[name]
        head = {"table": f"### [{name}]", "named": f"### [{name}.NAME]", "list": f"### [[{name}]]"}[style]
        table(schema, head)
    out.append("## Components (`[entities.NAME.COMPONENT]`)")
    out.append("")
    for name in sorted(COMPONENTS):
        table(COMPONENTS[name], f"### {name}")
    return "\n".join(out)


def run(args) -> int:
    if args.topic == "limits":
        from chainsim.game.records import plausible  # noqa: PLC0415 - the records server's rules, a section of the page

        print(limits.markdown([plausible.markdown()]), end="")
        return 0
    if args.topic == "models":
        print(model_params.markdown(), end="")
        return 0
    print(render_reference())
    return 0
