"""Where ``tune.py``'s study lives: an Optuna RDB storage that several processes can share.

Several processes (``--workers``, a second ``tune.py``, Ray tasks) open the same storage, each its
own connection. Optuna recommends a database server for that, or a journal file on one machine;
a SQLite file works on one machine with two precautions, both taken here:

- a writer waits for another's lock up to `SQLITE_TIMEOUT_S` seconds, where SQLite's
  default gives up after 5 s with "database is locked" (the remedy of Optuna's FAQ; a trial writes
  a few rows per validation, so the waits are short);
- processes opening a new file at once race to create its tables (one of them fails with "table
  already exists" or a unique-constraint error on the schema version): the opening is tried again,
  and then finds the tables made.

A SQLite file is not for several machines (its locks do not hold over NFS); a cluster shares a
database server (``postgresql://...``, ``mysql://...``).
"""

from __future__ import annotations

import os
import time
from typing import Any

#: Seconds a SQLite writer waits for another process's lock before failing.
SQLITE_TIMEOUT_S = 60.0
#: Times the storage is opened before its error counts (see the module's docstring).
OPEN_ATTEMPTS = 5


def open_storage(url: str) -> Any:
    """An `optuna.storages.RDBStorage` on ``url``, shared safely with other processes.

    Raises:
        Exception: whatever SQLAlchemy or Optuna raise for a bad or unreachable URL.
    """
    import optuna
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import IntegrityError, OperationalError

    parsed = make_url(url)
    engine_kwargs: dict[str, Any] = {}
    if parsed.get_backend_name() == "sqlite" and "timeout" not in parsed.query:
        engine_kwargs["connect_args"] = {"timeout": SQLITE_TIMEOUT_S}
    attempt = 1
    while True:
        try:
            return optuna.storages.RDBStorage(url, engine_kwargs=engine_kwargs)
        except (IntegrityError, OperationalError):  # another process is creating the tables
            if attempt == OPEN_ATTEMPTS:
                raise
            time.sleep(0.2 * attempt)
            attempt += 1


def shared_url(url: str) -> str | None:
    """``url`` as processes elsewhere must open it (a SQLite file by its absolute path: a Ray
    worker runs in another working directory), or None where it cannot be shared: SQLite in
    memory is private to one process."""
    from sqlalchemy.engine import make_url

    parsed = make_url(url)
    if parsed.get_backend_name() != "sqlite":
        return url
    if parsed.database in (None, "", ":memory:") or parsed.query.get("mode") == "memory":
        return None
    if os.path.isabs(parsed.database):
        return url
    return parsed.set(database=os.path.abspath(parsed.database)).render_as_string(
        hide_password=False
    )
