"""The cutting trainer's attempt in the trainee records: its figures, their words and units.

Every attempt of the trainer keeps these figures by name (the records' procedure-neutral figures,
schema version 13), beside the pack's own [metrics.NAME]; the records' pages, lists and exports say
them as declared here. `target` is the top layer once every step is done (the opening made) and "none"
before.
"""

from __future__ import annotations

from chainsim.systems.procedures.procedure import AttemptLayout, Column

#: the figures of a cutting attempt, in the order pages show them
COLUMNS: tuple[Column, ...] = (
    Column("duration_s", "Time", "s", "time_s"),
    Column("cut_length_mm", "Cut length", "mm", "cut_mm"),
    Column("links_cut", "Links cut", "", "links", whole=True),
    Column("max_stretch_ratio", "Largest stretch", "", "stretch"),
    Column("max_displacement_mm", "Largest displacement", "mm", "moved_mm"),
    Column("elements_moved", "Elements moved", "", "moved", whole=True),
    Column("forceps_time_s", "Forceps time", "s", "forceps_s"),
    Column("scissors_time_s", "Scissors time", "s", "scissors_s"),
)

LAYOUT = AttemptLayout(
    columns=COLUMNS,
    target_form="a layer's name",
    field_words={c.name: (c.words, c.units) for c in COLUMNS} | {"target": ("Opened", "")},
)
