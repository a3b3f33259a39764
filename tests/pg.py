"""A throwaway PostgreSQL server for the tests, started and stopped by the test that uses it.

Everything it runs is its own: a cluster made by ``initdb`` in a fresh folder (trust
authentication, superuser :data:`USER`, UTF8, locale C), its unix socket and log beside
it, a free TCP port on 127.0.0.1. A site's own PostgreSQL (its port 5432, its socket in
/var/run/postgresql) is not touched. ``postgres`` runs in the foreground as a child of the
test process and is stopped by its process id; should the test process be killed outright
(a scheduler's SIGKILL, a worker that crashed), a watchdog it started stops the server and
removes its folder: it waits on a pipe that only the test process holds open, which the
kernel closes when that process dies, however it dies.

PostgreSQL refuses to run as root, and the tests run as root (``make test`` in CI): then
initdb and postgres run as Debian's ``postgres`` user (``nobody`` where there is none),
which owns the folder. Needs Debian's ``postgresql`` (``make test`` installs it as root).
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import pwd
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

USER = "gyrocal"
DATABASE = "gyrocal"
PROGRAMS = ("initdb", "postgres")
# Who runs the server when root runs the tests: the user Debian's package makes, or one
# every Debian system has. None is created: a test does not add users to the machine.
RUN_AS = ("postgres", "nobody")


def bin_dir() -> Path | None:
    """The folder holding both initdb and postgres: the one PATH names first (resolved, so
    that a link to one program finds its own version's other), else Debian's
    /usr/lib/postgresql/<version>/bin of the highest version (Debian keeps them off PATH)."""
    initdb = shutil.which("initdb")
    if initdb is not None:
        folder = Path(initdb).resolve().parent
        if all((folder / p).is_file() for p in PROGRAMS):
            return folder
    versions = [d for d in Path("/usr/lib/postgresql").glob("*") if re.fullmatch(r"\d+(\.\d+)*", d.name)]
    for version in sorted(versions, key=lambda d: [int(n) for n in d.name.split(".")], reverse=True):
        if all((version / "bin" / p).is_file() for p in PROGRAMS):
            return version / "bin"
    return None


def run_as() -> pwd.struct_passwd | None:
    """The unprivileged user the server runs as: None when the tests are not root's (the
    server is then theirs)."""
    if os.geteuid() != 0:
        return None
    for name in RUN_AS:
        with contextlib.suppress(KeyError):
            return pwd.getpwnam(name)
    raise LookupError(f"no user to run PostgreSQL as (root may not): none of {', '.join(RUN_AS)}")


def found() -> dict[str, bool]:
    """What the server needs, for ``conftest.needs``."""
    try:
        user_ok = run_as() is not None or os.geteuid() != 0
    except LookupError:
        user_ok = False
    return {
        "initdb and postgres": bin_dir() is not None,
        f"a user to run PostgreSQL as, not root ({' or '.join(RUN_AS)})": user_ok,
        "psycopg": importlib.util.find_spec("psycopg") is not None,
    }


INSTALL = "Debian's postgresql, which make test installs as root; psycopg is a dependency of gyrocal"


def installed_version() -> str | None:
    """The server's version ("postgres (PostgreSQL) 15.18 (Debian 15.18-0+deb12u1)"), or None."""
    folder = bin_dir()
    if folder is None:
        return None
    out = subprocess.run([folder / "postgres", "--version"], capture_output=True, text=True)
    return out.stdout.strip() or None


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class Server:
    """A PostgreSQL server in a fresh folder; :meth:`start`, then :meth:`stop`."""

    def __init__(self, *settings: str, timeout: float = 60, folder: Path | None = None) -> None:
        """``settings``: more ``name=value`` server settings (``-c``), after the ones for speed
        (a later one wins). ``folder``: a lasting cluster there, made by the first start, used
        again by later ones and kept at stop (a benchmark's registry outlives its run)."""
        self.settings = settings
        self.timeout = timeout
        self.folder = None if folder is None else Path(folder)
        self.root: Path | None = None
        self.port = 0
        self.proc: subprocess.Popen | None = None
        self.watchdog: subprocess.Popen | None = None
        self.bin = bin_dir()
        self.user = run_as()

    def __enter__(self) -> Server:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def pid(self) -> int | None:
        """The postmaster's process id."""
        return self.proc.pid if self.proc is not None else None

    @property
    def data(self) -> Path:
        return self.root / "data"

    @property
    def log(self) -> Path:
        return self.root / "server.log"

    def url(self, database: str = DATABASE) -> str:
        return f"postgresql://{USER}@127.0.0.1:{self.port}/{database}"

    # -- starting ------------------------------------------------------------------
    def start(self) -> Server:
        if self.bin is None:
            raise FileNotFoundError(f"no initdb and postgres ({INSTALL})")
        # A folder of its own under the system's temporary folder, not pytest's: the
        # server's user must reach it, and pytest's is root's alone (0700).
        if self.folder is None:
            self.root = Path(tempfile.mkdtemp(prefix="gyrocal-pg-"))
        else:
            self.root = self.folder
            self.root.mkdir(parents=True, exist_ok=True)
        made = not (self.data / "PG_VERSION").is_file()
        try:
            if self.user is not None:
                os.chown(self.root, self.user.pw_uid, self.user.pw_gid)
            if made:
                self._run(
                    "initdb",
                    f"--pgdata={self.data}",
                    f"--username={USER}",
                    "--auth=trust",
                    "--encoding=UTF8",
                    "--locale=C",
                    "--no-sync",
                )
            # Another process may take the free port before the server binds it: a few tries.
            for _ in range(3):
                self.port = free_port()
                before = self.log.stat().st_size if self.log.exists() else 0
                self._spawn()
                if self._wait():
                    break
                said = self.log.read_bytes()[before:].decode(errors="replace")
                if not re.search(r"could not bind|Address already in use", said):
                    raise RuntimeError(f"the test PostgreSQL server did not start:\n{self.log_tail()}")
                self._end()
            else:
                raise RuntimeError(f"the test PostgreSQL server found no free port:\n{self.log_tail()}")
            if made:
                self.create_database(DATABASE)
        except BaseException:
            self.stop()
            raise
        return self

    def _env(self) -> dict[str, str]:
        """The environment without a user's PG* settings (another server's host or port)."""
        env = {k: v for k, v in os.environ.items() if not k.startswith("PG")}
        if self.user is not None:
            env.update(HOME=self.user.pw_dir, USER=self.user.pw_name, LOGNAME=self.user.pw_name)
        return env

    def _as_user(self) -> dict:
        """Popen's arguments that run a program in the folder, as the server's user if root
        runs the tests."""
        args = {"cwd": self.root, "env": self._env()}
        if self.user is not None:
            args.update(user=self.user.pw_uid, group=self.user.pw_gid, extra_groups=[])
        return args

    def _run(self, program: str, *args: str) -> None:
        out = subprocess.run(
            [self.bin / program, *args],
            capture_output=True,
            text=True,
            timeout=self.timeout,
            **self._as_user(),
        )
        if out.returncode != 0:
            raise RuntimeError(f"{program} failed ({out.returncode}):\n{out.stdout}{out.stderr}")

    def _spawn(self) -> None:
        settings = [
            "listen_addresses=127.0.0.1",
            # Nothing here outlives the test: no waiting for the disk.
            "fsync=off",
            "synchronous_commit=off",
            "full_page_writes=off",
            "shared_buffers=16MB",
            *self.settings,
        ]
        command = [self.bin / "postgres", "-D", self.data, "-p", str(self.port), "-k", self.root]
        for setting in settings:
            command += ["-c", setting]
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                command,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                **self._as_user(),
            )
        # In a session of its own: a terminal's Ctrl-C reaches the tests, not the watchdog.
        self.watchdog = subprocess.Popen(
            [
                sys.executable,
                "-c",
                WATCHDOG,
                str(self.proc.pid),
                str(self.data),
                "" if self.folder else str(self.root),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            start_new_session=True,
        )

    def _wait(self) -> bool:
        """Until the server takes connections (True), or it died (False); past the
        timeout, an error with its log."""
        import psycopg

        deadline = time.monotonic() + self.timeout
        while True:
            if self.proc.poll() is not None:
                return False
            try:
                psycopg.connect(self.url("postgres"), connect_timeout=2).close()
                return True
            except psycopg.OperationalError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError(
                    f"the test PostgreSQL server took no connection in {self.timeout:.0f} s:\n"
                    f"{self.log_tail()}"
                )
            time.sleep(0.05)

    def create_database(self, name: str, icu_locale: str | None = None) -> str:
        """A new, empty database; its URL. ``icu_locale`` ("en-US"): text in that language's
        order (a factory's database), not the cluster's byte order."""
        import psycopg
        from psycopg import sql

        statement = sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name))
        if icu_locale is not None:
            statement += sql.SQL(" LOCALE_PROVIDER icu ICU_LOCALE {} LOCALE 'C' TEMPLATE template0").format(
                sql.Literal(icu_locale)
            )
        with psycopg.connect(self.url("postgres"), autocommit=True) as conn:
            conn.execute(statement)
        return self.url(name)

    def log_tail(self, tail: int = 4000) -> str:
        if self.root is None or not self.log.exists():
            return ""
        return self.log.read_text(errors="replace")[-tail:]

    # -- stopping --------------------------------------------------------------------
    def stop(self) -> None:
        """Stop the server by its process id, remove the folder (a lasting one stays)."""
        self._end()
        if self.root is not None and self.folder is None:
            shutil.rmtree(self.root, ignore_errors=True)

    def _end(self) -> None:
        """SIGINT: PostgreSQL's fast shutdown (sessions ended, no waiting for clients).
        SIGKILL as the last resort, with the server processes it leaves (its children)."""
        proc, self.proc = self.proc, None
        watchdog, self.watchdog = self.watchdog, None
        try:
            self._stop(proc)
        finally:
            if watchdog is not None:  # told the server is stopped, it ends
                watchdog.communicate(b"stopped", timeout=60)

    @staticmethod
    def _stop(proc: subprocess.Popen | None) -> None:
        if proc is None or proc.poll() is not None:
            return
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            children = children_of(proc.pid)
            proc.kill()
            for pid in children:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            proc.wait(15)


# The watchdog (argv: the postmaster's pid, its data folder, the folder to remove or ""):
# reads its stdin until the pipe closes. Told "stopped", it ends (a start's retry uses the
# folder again); closed unsaid, the test process died: then, if the postmaster
# still runs (its command line names the data folder: not a reused pid), stops it as
# Server._end does, and removes the folder.
WATCHDOG = """
import os, shutil, signal, sys, time
pid, data, folder = int(sys.argv[1]), sys.argv[2], sys.argv[3]
if sys.stdin.buffer.read() == b"stopped":
    sys.exit()

def running():
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return data.encode() in f.read()
    except OSError:
        return False

for sig, grace in ((signal.SIGINT, 30), (signal.SIGKILL, 15)):
    if not running():
        break
    os.kill(pid, sig)
    deadline = time.monotonic() + grace
    while running() and time.monotonic() < deadline:
        time.sleep(0.05)
if folder:
    shutil.rmtree(folder, ignore_errors=True)
"""


def children_of(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (a postmaster's backends and workers)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            # The fourth field, after the command name in parentheses (which may hold spaces).
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found
