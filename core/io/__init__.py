"""Reading and writing measurement files: Renishaw .rtl/.rta logs (:mod:`.rtl`), generic tables
with a column map (:mod:`.table`), dynamic captures (:mod:`.capture`), ISO 230-2 target/run
tables (:mod:`.iso_table`) and plan.toml with the import of a whole plan (:mod:`.plan`).

Every reader raises :class:`volucal.core.userror.FormatError` naming the file and the line for
input it cannot accept, and nothing is partly imported. docs/formats.md describes the formats.
"""
