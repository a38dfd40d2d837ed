"""The monitor's store: runs, their rows, results, alarms, events and saved state in one database
(an SQLite file or a PostgreSQL database; `store.store` describes the schema)."""

from .databases import StoreError, is_url
from .store import LONGEST, TIMES, Commit, Run, Store, damaged, row_state

__all__ = ["LONGEST", "TIMES", "Commit", "Run", "Store", "StoreError", "damaged", "is_url", "row_state"]
