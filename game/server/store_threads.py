"""The records server's access to the store: a few worker threads, each with its own connection.

``RecordStore`` is a synchronous object holding one connection (sqlite3 connections belong to the
thread that opened them). The ASGI app never blocks its event loop on the database: every store
call runs on a small thread pool where each thread keeps its own ``RecordStore`` on the same
SQLite file or PostgreSQL database. SQLite serialises writers itself (WAL, ``BEGIN IMMEDIATE``)
and PostgreSQL through the store's advisory lock, so concurrent saves are safe on both.

A connection that failed (PostgreSQL restarted, network gone) is dropped and reopened on the
thread's next call; the request that saw the failure answers 503 so the client retries it.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from chainsim.game.records.backend import db_errors, is_postgres
from chainsim.game.records.store import RecordStore, WriteFailed

logger = logging.getLogger(__name__)
T = TypeVar("T")

# SQLite: readers run side by side in WAL mode, one writer at a time; PostgreSQL: one connection each.
THREADS = {"sqlite": 4, "postgresql": 8}


class Unavailable(Exception):
    """The database could not serve this request; it is safe to retry (HTTP 503)."""


class Storage:
    def __init__(self, db: str | None, threads: int | None = None) -> None:
        self.db = db
        self.kind = "postgresql" if is_postgres(db) else "sqlite"
        # Open once here: a bad file or URL is one UserError before the server starts listening,
        # and migrations run once rather than racing between worker threads.
        with RecordStore(db) as store:
            self.where = str(store.path)
        self._local = threading.local()
        self._pool = ThreadPoolExecutor(threads or THREADS[self.kind], thread_name_prefix="records")
        self._errors = db_errors()

    def _store(self) -> RecordStore:
        store = getattr(self._local, "store", None)
        if store is None:
            store = self._local.store = RecordStore(self.db)
        return store

    def _drop(self) -> None:
        store, self._local.store = getattr(self._local, "store", None), None
        if store is not None:
            try:
                store.close()
            except Exception:  # the connection is already broken; nothing more to release
                logger.debug("closing a failed records connection", exc_info=True)

    def _call(self, fn: Callable[..., T], *args: Any) -> T:
        try:
            return fn(self._store(), *args)
        except WriteFailed as exc:
            self._drop()
            raise Unavailable(str(exc)) from None
        except self._errors as exc:
            logger.warning("records database error: %s", exc)
            self._drop()
            raise Unavailable(
                f"records database error: {str(exc).strip().splitlines()[0] if str(exc) else exc}"
            ) from None

    async def run(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(store, *args)`` on a worker thread's store."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._pool, self._call, fn, *args)

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)
