"""Procedure systems: one folder per procedure the app can run (its steps, scoring and feedback).

PROCEDURES is the one table of them, by the name a pack gives in `pack.procedure`: packs refer to
procedures by name and never carry code. The needle procedure is generic: a pack describes its own
needle procedure in data (docs/needle-procedures.md); "prp" is that procedure's former name, kept so
packs written for it still load.
"""

# procedure name -> "module:function" (the function installs the procedure's systems on an App)
PROCEDURES: dict[str, str] = {
    "needle": "chainsim.systems.procedures.needle.procedure:plugin",
    "prp": "chainsim.systems.procedures.needle.procedure:plugin",
    "cutting": "chainsim.systems.procedures.cutting.procedure:plugin",
    "demo": "chainsim.systems.procedures.demo.procedure:plugin",
}
