"""Procedure systems: one folder per procedure the app can run (its steps, scoring and feedback).

PROCEDURES is the one table of them, by the name a pack gives in `pack.procedure`: packs refer to
procedures by name and never carry code. Each entry is the procedure's `Procedure` (procedure.py),
declared in its folder's light `declaration` module: the shell reads what a procedure declares through
it and imports no procedure's package. The needle procedure is generic: a pack describes its own
needle procedure in data (docs/needle-procedures.md); "prp" is that procedure's former name, kept so
packs written for it still load.

Beside the procedures' folders, modules that belong to none: procedure.py (what a procedure declares)
and verdicts.py (an attempt's metrics judged against a pack's benchmarks, for every procedure).
"""

from __future__ import annotations

from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures.cutting.declaration import PROCEDURE as CUTTING
from chainsim.systems.procedures.demo.declaration import PROCEDURE as DEMO
from chainsim.systems.procedures.needle.declaration import PROCEDURE as NEEDLE
from chainsim.systems.procedures.procedure import AttemptLayout, Procedure, Study

# procedure name -> the procedure
PROCEDURES: dict[str, Procedure] = {
    "needle": NEEDLE,
    "prp": NEEDLE,
    "cutting": CUTTING,
    "demo": DEMO,
}


def procedure_for(name: str) -> Procedure:
    """The procedure a pack names in `pack.procedure`; an unknown name is an error that lists the known."""
    try:
        return PROCEDURES[name]
    except KeyError:
        raise UserError(f"unknown procedure '{name}'; built-in procedures: {', '.join(sorted(PROCEDURES))}") from None


def procedure_of(manifest: dict) -> Procedure | None:
    """The procedure of a pack's manifest (its `pack.procedure`), or None for a pack without one."""
    name = (manifest.get("pack") or {}).get("procedure") or ""
    return procedure_for(name) if name else None


#: the procedure the trainee records were made for: its metrics are the attempts table's fixed columns
#: (schema versions 1-5), and its study (thesis 6.1.2-6.1.5) is the one the study screens and
#: `chainsim protocol` run
RECORDS_PROCEDURE: Procedure = NEEDLE


def records_layout() -> AttemptLayout:
    """The attempt layout of the procedure whose metrics the attempts table keeps as fixed columns."""
    assert RECORDS_PROCEDURE.layout is not None
    return RECORDS_PROCEDURE.layout


def records_study() -> Study:
    """The study the study screens and `chainsim protocol` run (RECORDS_PROCEDURE's)."""
    assert RECORDS_PROCEDURE.study is not None
    return RECORDS_PROCEDURE.study
