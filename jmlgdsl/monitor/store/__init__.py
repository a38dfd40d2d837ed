"""The monitor's store, the one place of the package that speaks SQL: runs, their rows, results,
alarms, operators' actions, events and the saved state they were diagnosed with, in an SQLite file
or a PostgreSQL database.

    records    the values it takes and gives back (Run, Alarm, Action, Sample, Finished, Verdict,
               Commit, Saved): what a reader or a writer sees of it
    store      `Store`: opening, the one write (`save`, `act`) and the queries readers need
    schema     the tables, and the upgrades of an older store to them
    databases  SQLite and PostgreSQL: the few differences between the engines
    export     a run as its result table, and its rows as a data file (`jmlgdsl export`)

A store kept some other way than in SQL would be another `Store` with the same methods, handing
out the same records.
"""

from .databases import StoreError, is_url
from .export import Exported, write_samples, write_table
from .records import LONGEST, TIMES, Action, Alarm, Commit, Finished, Run, Sample, Saved, Verdict, row_state
from .store import Store, damaged

__all__ = ["LONGEST", "TIMES", "Action", "Alarm", "Commit", "Exported", "Finished", "Run", "Sample", "Saved", "Store",
           "StoreError", "Verdict", "damaged", "is_url", "row_state", "write_samples", "write_table"]
