"""A private, throwaway PostgreSQL server for tests: initdb into a temporary directory, the server on a
unix socket only (no TCP), databases created on demand, stopped and removed at the end.

PostgreSQL refuses to run as root; as root the server runs as the `postgres` system user (setpriv, which
execs in place, so the process we hold is the postmaster itself) and its directories are chowned to it.
"""
from __future__ import annotations

import glob
import itertools
import os
import pwd
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

START_DEADLINE_S = 30.0  # from launch to accepting connections; typically ~1 s
SUPERUSER = "postgres"


class PostgresUnavailable(RuntimeError):
    """What is missing to run a server here (binaries, the postgres user); one line."""


def find_binaries() -> Path:
    """The directory of initdb/postgres/pg_ctl: on PATH, else Debian's /usr/lib/postgresql/N/bin (the
    `postgresql` package does not put them on PATH), newest version first."""
    found = shutil.which("initdb")
    candidates = [Path(found).resolve().parent] if found else []
    candidates += [Path(d) for d in sorted(glob.glob("/usr/lib/postgresql/*/bin"),
                                           key=lambda d: int(Path(d).parent.name) if Path(d).parent.name.isdigit()
                                           else 0, reverse=True)]
    for directory in candidates:
        if all((directory / tool).is_file() for tool in ("initdb", "postgres", "pg_ctl")):
            return directory
    raise PostgresUnavailable("PostgreSQL server binaries (initdb, postgres, pg_ctl) not found on PATH or in "
                              "/usr/lib/postgresql/*/bin (apt-get install postgresql)")


class PostgresServer:
    """`with PostgresServer() as server: url = server.create_database("h")`."""

    def __init__(self) -> None:
        self.bin = find_binaries()
        self._as_user: list[str] = []
        if os.geteuid() == 0:
            try:
                user = pwd.getpwnam(SUPERUSER)
            except KeyError:
                raise PostgresUnavailable("running as root and there is no 'postgres' system user to run the "
                                          "server as (PostgreSQL refuses root)") from None
            self._uid, self._gid = user.pw_uid, user.pw_gid
            self._as_user = ["setpriv", f"--reuid={user.pw_uid}", f"--regid={user.pw_gid}", "--init-groups", "--"]
        # Short, under /tmp: a unix socket path is limited to ~100 bytes, and pytest's tmp_path is both
        # longer and closed (0700 root) to the postgres user.
        self.base = Path(tempfile.mkdtemp(prefix="accel-pg-"))
        self.data = self.base / "data"
        self.socket_dir = self.base / "socket"
        self.log = self.base / "server.log"
        self.process: subprocess.Popen[bytes] | None = None
        self._numbers = itertools.count()

    def _run(self, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*self._as_user, *args], capture_output=True, text=True, check=False,
                              timeout=START_DEADLINE_S, cwd=self.base)

    def start(self) -> PostgresServer:
        self.socket_dir.mkdir()
        if self._as_user:
            for path in (self.base, self.socket_dir):
                os.chown(path, self._uid, self._gid)
        # trust: the socket is in a private 0700 directory; --no-sync and the settings below: a throwaway
        # server needs no durability, only the same SQL, locking and isolation as a real one.
        init = self._run(str(self.bin / "initdb"), "-D", str(self.data), "-U", SUPERUSER, "-A", "trust",
                         "-E", "UTF8", "--locale=C.UTF-8", "--no-sync", "--no-instructions")
        if init.returncode != 0:
            raise RuntimeError(f"initdb failed: {(init.stderr or init.stdout).strip()}")
        with open(self.log, "wb") as log:
            self.process = subprocess.Popen(
                [*self._as_user, str(self.bin / "postgres"), "-D", str(self.data), "-k", str(self.socket_dir),
                 "-c", "listen_addresses=", "-c", "fsync=off", "-c", "synchronous_commit=off",
                 "-c", "full_page_writes=off", "-c", "max_connections=50"],
                stdout=log, stderr=subprocess.STDOUT, cwd=self.base)
        self._wait_until_ready()
        return self

    def _wait_until_ready(self) -> None:
        import psycopg

        assert self.process is not None
        deadline = time.monotonic() + START_DEADLINE_S
        while True:
            try:
                psycopg.connect(self.conninfo("postgres"), connect_timeout=5).close()
                return
            except psycopg.OperationalError as error:
                last = str(error).strip().splitlines()[0]
            if time.monotonic() > deadline:
                raise RuntimeError(f"PostgreSQL not accepting connections after {START_DEADLINE_S:.0f} s: {last}; "
                                   f"log: {self.log_tail()}")
            try:  # waits on the server dying, which is also the retry interval while it starts
                code = self.process.wait(timeout=0.05)
            except subprocess.TimeoutExpired:
                continue
            raise RuntimeError(f"PostgreSQL exited with {code} while starting: {self.log_tail()}")

    def log_tail(self) -> str:
        try:
            return " | ".join(self.log.read_text(errors="replace").strip().splitlines()[-5:])
        except OSError:
            return "(no log)"

    def conninfo(self, database: str) -> str:
        return f"host={self.socket_dir} user={SUPERUSER} dbname={database}"

    def url(self, database: str) -> str:
        """The SQLAlchemy URL of one of its databases (psycopg 3, over the socket)."""
        return f"postgresql+psycopg://{SUPERUSER}@/{database}?host={self.socket_dir}"

    def create_database(self, name: str, icu_locale: str | None = "en-US", **settings: str) -> str:
        """A new database, named `name` and a number of its own; its URL. ICU en-US collation by default, as on
        a typical shared server (whose string order is not the code point order of this server's C locale);
        `settings` become its defaults (ALTER DATABASE .. SET name = value), e.g. default_transaction_isolation.
        The number: the server lives for the session, and a module's fixture that makes a database is set up
        again whenever tests of other modules run in between (a shuffled order)."""
        import psycopg
        from psycopg import sql

        name = f"{name}_{next(self._numbers)}"
        collation = sql.SQL("")
        if icu_locale:
            collation = sql.SQL(" TEMPLATE template0 LOCALE_PROVIDER icu ICU_LOCALE {}").format(icu_locale)
        with psycopg.connect(self.conninfo("postgres"), autocommit=True) as connection:
            connection.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)) + collation)
            for key, value in settings.items():
                connection.execute(sql.SQL("ALTER DATABASE {} SET {} = {}").format(
                    sql.Identifier(name), sql.Identifier(key), sql.Literal(value)))
        return self.url(name)

    def stop(self) -> None:
        try:
            if self.process is not None and self.process.poll() is None:
                stop = self._run(str(self.bin / "pg_ctl"), "stop", "-D", str(self.data), "-m", "fast", "-w")
                try:
                    self.process.wait(timeout=START_DEADLINE_S)
                except subprocess.TimeoutExpired:
                    self.process.kill()  # only the postmaster we started, by its own handle
                    self.process.wait()
                    raise RuntimeError(f"PostgreSQL did not stop: {stop.stderr.strip()}") from None
        finally:
            shutil.rmtree(self.base, ignore_errors=True)

    def __enter__(self) -> PostgresServer:
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *_exc: object) -> None:
        self.stop()
