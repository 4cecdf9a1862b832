"""Procedure systems: one folder per procedure the app can run (its steps, scoring and feedback).

PROCEDURES is the one table of them, by the name a pack gives in `pack.procedure`: packs refer to
procedures by name and never carry code.
"""

# procedure name -> "module:function" (the function installs the procedure's systems on an App)
PROCEDURES: dict[str, str] = {
    "prp": "chainsim.systems.procedures.prp.procedure:plugin",
    "cutting": "chainsim.systems.procedures.cutting.procedure:plugin",
    "demo": "chainsim.systems.procedures.demo.procedure:plugin",
}
