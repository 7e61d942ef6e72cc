"""The results of a batch run in SQLite: one row per dataset, written as each one finishes.

One process writes (the batch's parent), each row in its own transaction; the database is in
WAL mode with full synchronisation, so a run killed at any moment (SIGKILL included) keeps
every row it committed and nothing half-written. A row is keyed on the dataset, the spec's
hash and the options (:meth:`kanagen.fitjob.FitOptions.key`): a re-run of the same command
skips what is done, and a row is never duplicated. (WAL needs a local file system, as SQLite
says: keep the database off network shares.)
"""

from __future__ import annotations

import json
import os
import socket
import sqlite3
import time
import uuid
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

SCHEMA_VERSION = 1

#: Outcome of a dataset: a model found (``ok``), none found or not converged
#: (``no model``), or the dataset failed (``error``: unreadable, a crash...).
STATUSES = ("ok", "no model", "error")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS results (
    dataset TEXT NOT NULL,
    spec_sha256 TEXT NOT NULL,
    options TEXT NOT NULL,          -- canonical JSON of the options and the channel
    family TEXT NOT NULL,
    channel TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('ok', 'no model', 'error')),
    model TEXT,                     -- the chosen model
    estimate TEXT,                  -- JSON {component: value}, parameter then slacks
    std TEXT,                       -- JSON {component: standard deviation}
    info TEXT,                      -- JSON matrix Q~ (report eq. 6), rows as components
    inliers TEXT,                   -- JSON list of measure ids (rows of the dataset)
    n_inliers INTEGER,
    measures INTEGER,
    cost REAL,                      -- L~^2/d: the record's normalized_cost
    dof INTEGER,
    message TEXT,                   -- why the search stopped, or the error
    seconds REAL,                   -- estimation time of the dataset
    finished TEXT NOT NULL,         -- UTC, ISO 8601
    record TEXT,                    -- the full JSON record (kanagen fit --json)
    PRIMARY KEY (dataset, spec_sha256, options)
);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS claims (   -- datasets a running batch has taken
    dataset TEXT NOT NULL,
    spec_sha256 TEXT NOT NULL,
    options TEXT NOT NULL,
    owner TEXT NOT NULL,            -- host:pid:run of the batch
    PRIMARY KEY (dataset, spec_sha256, options)
);
"""

_COLUMNS = ("dataset", "spec_sha256", "options", "family", "channel", "status", "model",
            "estimate", "std", "info", "inliers", "n_inliers", "measures", "cost", "dof",
            "message", "seconds", "finished", "record")
_JSON = ("estimate", "std", "info", "inliers")


@dataclass(frozen=True)
class Encoded:
    """A record made ready for its row: the queryable columns and the record as JSON text
    (made where the dataset was estimated, so the one writer only writes)."""

    model: str | None = None
    estimate: str | None = None
    std: str | None = None
    info: str | None = None
    inliers: str | None = None
    n_inliers: int | None = None
    measures: int | None = None
    cost: float | None = None
    dof: int | None = None
    record: str | None = None


def encode(record: dict | None) -> Encoded:
    """The columns of a JSON record (``kanagen fit --json``; None: a failed dataset)."""
    if record is None:
        return Encoded()
    estimate = {**(record.get("params") or {}), **(record.get("slacks") or {})} or None
    inliers = record.get("inliers")
    if record.get("local") and record.get("success"):
        inliers = list(range(_count(record)))  # the local fit takes every measure
    return Encoded(record.get("model"), _dumps(estimate), _dumps(record.get("std")),
                   _dumps(record.get("info")), _dumps(inliers),
                   None if inliers is None else len(inliers), _count(record),
                   record.get("normalized_cost"),
                   record.get("dof"), _dumps(record))


@dataclass(frozen=True)
class Row:
    """One dataset's outcome, as written."""

    dataset: str
    spec_sha256: str
    options: str
    family: str
    channel: str
    status: str
    encoded: Encoded = Encoded()  # :func:`encode` of its record (empty on error)
    message: str = ""
    seconds: float | None = None

    def values(self) -> tuple:
        e = self.encoded
        return (self.dataset, self.spec_sha256, self.options, self.family, self.channel,
                self.status, e.model, e.estimate, e.std, e.info, e.inliers, e.n_inliers,
                e.measures, e.cost, e.dof, self.message, self.seconds,
                datetime.now(UTC).isoformat(timespec="milliseconds"), e.record)


def _count(rec: dict) -> int | None:
    measures = rec.get("measures")
    if isinstance(measures, dict):  # a local fit's corrected measures
        return sum(len(v) for v in measures.values())
    return measures


def _dumps(obj) -> str | None:
    return None if obj is None else json.dumps(obj, allow_nan=False, separators=(",", ":"))


class ResultsDB:
    """A results database opened (and created) for writing; a context manager.

    Parameters
    ----------
    path : path of the SQLite file (created, with its folder, when missing). An existing
        SQLite file that is not a kanagen results database is refused before anything in it
        changes (kanagen's databases carry :data:`APPLICATION_ID`).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = _connect(self.path)
            self._db.execute("PRAGMA schema_version").fetchone()  # opens the file
        except (OSError, sqlite3.DatabaseError) as exc:
            if "not a database" in str(exc):
                raise ValueError(f"{self.path}: not a kanagen results database ({exc})") \
                    from None
            raise ValueError(f"cannot open the results database {self.path}: "
                             f"{getattr(exc, 'strerror', None) or exc}") from None
        try:
            _adopt(self._db, self.path)
            _retry(lambda: self._db.execute("PRAGMA journal_mode=WAL"))
            self._db.execute("PRAGMA synchronous=FULL")  # a committed row survives anything
            _check_schema(self._db, self.path)
        except (sqlite3.DatabaseError, ValueError) as exc:
            self._db.close()
            if isinstance(exc, ValueError):
                raise
            raise ValueError(f"{self.path}: not a kanagen results database ({exc})") from None

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> ResultsDB:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def done(self, spec_sha256: str, options: str, retry_errors: bool = False) -> set[str]:
        """Datasets already recorded for this spec and these options (failed ones too,
        unless ``retry_errors``)."""
        sql = "SELECT dataset FROM results WHERE spec_sha256 = ? AND options = ?"
        if retry_errors:
            sql += " AND status != 'error'"
        return {r[0] for r in self._db.execute(sql, (spec_sha256, options))}

    def claim(self, dataset: str, spec_sha256: str, options: str, owner: str,
              retry_errors: bool = False) -> bool:
        """Take ``dataset`` for this run (``owner``), in one transaction: False when it has
        a result already (a failed one counts unless ``retry_errors``) or another live run
        holds it (:func:`_alive`). Two runs on one database so estimate each dataset once."""
        with _transaction(self._db):
            row = self._db.execute(
                "SELECT status FROM results WHERE dataset = ? AND spec_sha256 = ? AND "
                "options = ?", (dataset, spec_sha256, options)).fetchone()
            if row is not None and (row[0] != "error" or not retry_errors):
                return False
            held = self._db.execute(
                "SELECT owner FROM claims WHERE dataset = ? AND spec_sha256 = ? AND "
                "options = ?", (dataset, spec_sha256, options)).fetchone()
            if held is not None and held[0] != owner and _alive(held[0]):
                return False
            self._db.execute("INSERT OR REPLACE INTO claims VALUES (?, ?, ?, ?)",
                             (dataset, spec_sha256, options, owner))
        return True

    def release(self, owner: str) -> None:
        """Drop this run's claims (its datasets not estimated: a later run takes them)."""
        with _transaction(self._db):
            self._db.execute("DELETE FROM claims WHERE owner = ?", (owner,))

    def write(self, row: Row) -> bool:
        """Record one dataset in its own transaction (its claim dropped); True when written.
        A failed dataset's row is replaced by a new outcome; any other row is kept (the
        first writer wins)."""
        if row.status not in STATUSES:
            raise ValueError(f"unknown status {row.status!r}")
        updates = ", ".join(f"{c} = excluded.{c}" for c in _COLUMNS[3:])
        with _transaction(self._db):
            cur = self._db.execute(
                f"INSERT INTO results ({', '.join(_COLUMNS)}) "
                f"VALUES ({', '.join('?' * len(_COLUMNS))}) "
                f"ON CONFLICT (dataset, spec_sha256, options) DO UPDATE SET {updates} "
                "WHERE results.status = 'error'", row.values())
            self._db.execute("DELETE FROM claims WHERE dataset = ? AND spec_sha256 = ? AND "
                             "options = ?", (row.dataset, row.spec_sha256, row.options))
        return cur.rowcount > 0


#: ``PRAGMA application_id`` of a kanagen results database ("KGRS").
APPLICATION_ID = 0x4B475253


def _adopt(db: sqlite3.Connection, path: Path) -> None:
    """Make ``db`` a kanagen results database — a new (empty) file, or one that is one
    already — or refuse it, changing nothing: an unrelated SQLite file passed as ``--db``
    must not gain kanagen's tables and WAL mode."""
    with _transaction(db):
        app = db.execute("PRAGMA application_id").fetchone()[0]
        tables = {r[0] for r in db.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table'")}
        ours = app == APPLICATION_ID or (app == 0 and {"results", "meta"} <= tables)
        if tables and not ours:
            raise ValueError(f"{path}: an SQLite database that is not a kanagen results "
                             f"database (tables: {', '.join(sorted(tables)[:8])}); give "
                             "another --db")
        for statement in _SCHEMA.split(";"):
            if statement.strip():
                db.execute(statement)
        db.execute("INSERT OR IGNORE INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))
        db.execute(f"PRAGMA application_id = {APPLICATION_ID}")


def _retry(action, seconds: float = 60.0):
    """``action()``, again while another connection holds the lock it needs (switching to
    WAL takes an exclusive lock that SQLite's busy timeout does not wait for)."""
    deadline = time.monotonic() + seconds
    while True:
        try:
            return action()
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def _alive(owner: str) -> bool:
    """Whether the run that wrote a claim (``host:pid:run``) may still be running: on this
    host, its process exists; on another host it is presumed alive."""
    host, _, rest = owner.partition(":")
    pid = rest.partition(":")[0]
    if host != socket.gethostname():
        return True
    try:
        os.kill(int(pid), 0)
    except (ValueError, ProcessLookupError):
        return False
    except PermissionError:
        return True
    return True


def claim_owner() -> str:
    """This run's name in the claims table: ``host:pid:random``."""
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


class _transaction:
    """``BEGIN IMMEDIATE`` ... ``COMMIT``, or ``ROLLBACK`` on any exception."""

    def __init__(self, db: sqlite3.Connection):
        self.db = db

    def __enter__(self):
        self.db.execute("BEGIN IMMEDIATE")

    def __exit__(self, kind, value, tb):
        self.db.execute("COMMIT" if kind is None else "ROLLBACK")


def _connect(path: Path, existing: bool = False) -> sqlite3.Connection:
    if existing and not path.is_file():
        raise ValueError(f"{path}: no such results database")
    return sqlite3.connect(path, timeout=60, isolation_level=None)


def _check_schema(db: sqlite3.Connection, path: Path) -> None:
    row = db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
    if row is None or row[0] != str(SCHEMA_VERSION):
        raise ValueError(f"{path}: results schema {row and row[0]}, this kanagen reads "
                         f"{SCHEMA_VERSION}")


def read_results(db: str | Path, dataset: str | None = None, *, as_frame: bool = False,
                 with_record: bool = False):
    """The results table: a list of records (dicts), or a pandas DataFrame.

    Parameters
    ----------
    db : path of the results database.
    dataset : str, optional
        Only this dataset's rows.
    as_frame : bool
        Return a ``pandas.DataFrame`` (pandas must be installed).
    with_record : bool
        Include the full JSON record of each row (key ``record``; large).

    JSON columns (``estimate``, ``std``, ``info``, ``inliers``) come decoded; rows in the
    order they finished.
    """
    if as_frame:
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("read_results(as_frame=True) needs pandas: pip install pandas")\
                from None
    path = Path(db)
    columns = [c for c in _COLUMNS if with_record or c != "record"]
    con = _connect(path, existing=True)
    try:
        _check_schema(con, path)
        sql = f"SELECT {', '.join(columns)} FROM results"
        args: tuple = ()
        if dataset is not None:
            sql, args = sql + " WHERE dataset = ?", (dataset,)
        rows = con.execute(sql + " ORDER BY finished, rowid", args).fetchall()
    except sqlite3.DatabaseError as exc:
        raise ValueError(f"{path}: not a kanagen results database ({exc})") from None
    finally:
        con.close()
    records = [_decode(dict(zip(columns, r, strict=True))) for r in rows]
    return pd.DataFrame(records, columns=columns) if as_frame else records


def _decode(rec: dict) -> dict:
    for name in (*_JSON, "record"):
        if rec.get(name) is not None:
            rec[name] = json.loads(rec[name])
    return rec


def read_record(db: str | Path, dataset: str) -> tuple[dict, dict]:
    """The JSON record of ``dataset`` and its row (the last run that recorded it); ValueError
    when there is none, or when the dataset failed (its error in the message)."""
    rows = read_results(db, dataset, with_record=True)
    if not rows:
        names = sorted({r["dataset"] for r in read_results(db)})
        hint = f"; it has {', '.join(names[:5])}{' ...' if len(names) > 5 else ''}" \
            if names else "; it is empty"
        raise ValueError(f"{db}: no dataset {dataset!r}{hint}")
    row = rows[-1]
    if row["record"] is None:
        raise ValueError(f"{db}: dataset {dataset!r} failed: {row['message']}")
    return row.pop("record"), row
