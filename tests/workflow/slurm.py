"""A one-node SLURM cluster for the tests, started and stopped by the test that uses it.

Everything it runs is its own: a munge key and socket, a ``slurm.conf`` written for this
machine (the node's CPUs, sockets and memory as ``slurmd -C`` reads them; free ports),
state, spool and logs in a fresh folder. The clients find it through ``SLURM_CONF``
(:attr:`Cluster.env`), so another cluster on the same machine (a second test session, a
site's own SLURM) is not touched. munged, slurmctld and slurmd run in the foreground as
children of the test process and are stopped by their process ids, with every process
the cluster's jobs left behind (found by the ``SLURM_CONF`` in their environment).

Needs Debian's ``slurm-wlm`` and ``munge`` (``make test`` installs them as root) and root:
slurmd starts jobs as the user who submitted them.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

DAEMONS = ("munged", "slurmctld", "slurmd")
CLIENTS = ("sbatch", "squeue", "scancel", "scontrol", "sinfo", "srun")


def which(tool: str) -> str | None:
    """A SLURM or munge program: daemons live in /usr/sbin, outside a user's PATH."""
    return shutil.which(tool) or shutil.which(tool, path="/usr/sbin:/sbin")


def found() -> dict[str, bool]:
    """What the cluster needs, for ``conftest.needs``."""
    return {
        **{tool: which(tool) is not None for tool in DAEMONS + CLIENTS},
        "root (slurmd starts jobs as their user)": os.geteuid() == 0,
    }


INSTALL = "Debian's slurm-wlm and munge, which make test installs as root"


def installed_version() -> str | None:
    """The installed SLURM's version ("slurm-wlm 22.05.8"), or None. Asked of slurmd:
    the clients will not even print theirs without a cluster's configuration."""
    slurmd = which("slurmd")
    if slurmd is None:
        return None
    out = subprocess.run([slurmd, "-V"], capture_output=True, text=True)
    return out.stdout.strip() or None


def seconds(text: str) -> int:
    """A SLURM duration (``[days-][hours:]minutes:seconds``, as squeue prints a time limit)
    in seconds."""
    days, _, clock = text.rpartition("-")
    parts = [int(p) for p in clock.split(":")]
    while len(parts) < 3:
        parts.insert(0, 0)
    hours, minutes, secs = parts
    return ((int(days or 0) * 24 + hours) * 60 + minutes) * 60 + secs


def memory_mb(text: str) -> float:
    """squeue's memory (``2000M``, ``4G``) in MB."""
    scale = {"K": 1 / 1024, "M": 1, "G": 1024, "T": 1024**2}
    return float(text[:-1]) * scale[text[-1]] if text[-1] in scale else float(text)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def node_line() -> str:
    """This machine as slurmd sees it: ``CPUs=2 Boards=1 SocketsPerBoard=1
    CoresPerSocket=2 ThreadsPerCore=1 RealMemory=24152`` (what it would refuse more of)."""
    out = subprocess.run([which("slurmd"), "-C"], capture_output=True, text=True, check=True)
    first = out.stdout.splitlines()[0]
    return " ".join(f for f in first.split() if not f.startswith("NodeName="))


class Cluster:
    """A one-node SLURM cluster in a fresh folder; :meth:`start`, then :meth:`stop`."""

    node = "gyrocal1"

    def __init__(self) -> None:
        self.root: Path | None = None
        self.socket: Path | None = None
        self.conf: Path | None = None
        self.procs: dict[str, subprocess.Popen] = {}
        self.env: dict[str, str] = {}
        self.version = ""

    def __enter__(self) -> Cluster:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- the daemons ---------------------------------------------------------------
    def start(self) -> Cluster:
        # munged refuses a socket in a folder that not everyone can search, and so every
        # folder above it: a folder of its own under the system's temporary folder, not
        # pytest's (0700). The key stays in a folder only its owner reads.
        self.root = Path(tempfile.mkdtemp(prefix="gyrocal-slurm-"))
        self.root.chmod(0o755)
        for sub in ("key", "run", "state", "spool", "log"):
            (self.root / sub).mkdir(mode=0o700 if sub == "key" else 0o755)
        key = self.root / "key" / "munge.key"
        key.write_bytes(os.urandom(128))
        key.chmod(0o400)
        self.socket = self.root / "run" / "munge.socket"
        self.conf = self.root / "slurm.conf"
        self.conf.write_text(self.config(node_line()))
        self.env = {
            **os.environ,
            "SLURM_CONF": str(self.conf),
            "PATH": f"{self.shims()}{os.pathsep}{os.environ.get('PATH', '')}",
        }
        try:
            self._spawn(
                "munged",
                [
                    which("munged"),
                    "--foreground",
                    f"--key-file={key}",
                    f"--socket={self.socket}",
                    f"--pid-file={self.root / 'run' / 'munged.pid'}",
                    f"--log-file={self.root / 'log' / 'munged.log'}",
                    f"--seed-file={self.root / 'key' / 'munged.seed'}",
                ],
            )
            self._wait(lambda: self.socket.exists(), "munged's socket", 20)
            self._spawn("slurmctld", [which("slurmctld"), "-D"])
            self.start_slurmd()
            self.version = self.client("scontrol", "--version").stdout.strip()
            self.wait_idle()
        except BaseException:
            self.stop()
            raise
        return self

    def config(self, node: str) -> str:
        host = socket.gethostname()
        root = self.root
        return f"""# A one-node cluster for gyrocal's tests (tests/workflow/slurm.py)
ClusterName=gyrocaltest
SlurmctldHost={host}(127.0.0.1)
SlurmctldPort={free_port()}
SlurmdPort={free_port()}
SlurmUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket={self.socket}
StateSaveLocation={root / "state"}
SlurmdSpoolDir={root / "spool"}
SlurmctldPidFile={root / "run" / "slurmctld.pid"}
SlurmdPidFile={root / "run" / "slurmd.pid"}
SlurmctldLogFile={root / "log" / "slurmctld.log"}
SlurmdLogFile={root / "log" / "slurmd.log"}
MailProg=/bin/true
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
# Finished jobs stay visible to squeue for 10 minutes: without accounting, squeue is how
# Snakemake's SLURM plugin learns that a job ended and how.
MinJobAge=600
# A job cancelled or past its time limit is killed 5 s after its SIGTERM (default 30).
KillWait=5
# The node takes jobs again as soon as its slurmd registers after a restart.
ReturnToService=2
NodeName={self.node} NodeHostname={host} NodeAddr=127.0.0.1 {node} State=UNKNOWN
PartitionName=test Nodes={self.node} Default=YES MaxTime=INFINITE State=UP
"""

    def shims(self) -> Path:
        """A folder of programs put first on the cluster's PATH: an ``srun`` that puts
        ``SLURM_CONF`` back. snakemake-executor-plugin-slurm-jobstep (0.6.1) runs each job
        with ``srun`` in an environment stripped of all but a few ``SLURM_`` variables,
        ``SLURM_CONF`` among the dropped: srun then looks for /etc/slurm/slurm.conf, which
        a site's SLURM has and this cluster, which must not touch the machine's, has not."""
        folder = self.root / "bin"
        folder.mkdir(exist_ok=True)
        shim = folder / "srun"
        shim.write_text(
            f'#!/bin/sh\nexport SLURM_CONF="${{SLURM_CONF:-{self.conf}}}"\nexec {which("srun")} "$@"\n'
        )
        shim.chmod(0o755)
        return folder

    def start_slurmd(self) -> None:
        self._spawn("slurmd", [which("slurmd"), "-D", "-N", self.node])

    def restart_slurmd(self) -> None:
        """The node's daemon stopped and started again (its jobs' steps live on)."""
        self._end(self.procs.pop("slurmd"))
        self.start_slurmd()

    def _spawn(self, name: str, command: list[str]) -> None:
        with open(self.root / "log" / f"{name}.out", "ab") as log:
            self.procs[name] = subprocess.Popen(
                command, env=self.env, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
            )

    def _wait(self, ready, what: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not ready():
            dead = [name for name, p in self.procs.items() if p.poll() is not None]
            if dead or time.monotonic() > deadline:
                raise RuntimeError(
                    f"the test cluster's {what} did not come up "
                    f"({', '.join(dead) or 'timed out'}):\n{self.logs()}"
                )
            time.sleep(0.1)

    def wait_idle(self, timeout: float = 60) -> None:
        """Until the node takes jobs."""

        def idle():
            out = self.client("sinfo", "--noheader", "--format=%T", check=False)
            return out.returncode == 0 and out.stdout.strip() in ("idle", "mixed", "allocated")

        self._wait(idle, "node", timeout)

    # -- clients -------------------------------------------------------------------
    def client(self, tool: str, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        return subprocess.run(
            [which(tool), *args], env=self.env, capture_output=True, text=True, check=check, timeout=60
        )

    def jobs(self) -> list[dict[str, str]]:
        """Every job the controller knows (finished ones for MinJobAge): id, name, state,
        time limit, memory, CPUs, comment (the plugin's rule or group), time used, and
        when it was submitted, started and ended."""
        fields = {
            "id": "%i",
            "name": "%j",
            "state": "%T",
            "time_limit": "%l",
            "memory": "%m",
            "cpus": "%C",
            "comment": "%k",
            "elapsed": "%M",
            "submitted": "%V",
            "started": "%S",
            "ended": "%e",
        }
        out = self.client("squeue", "--states=all", "--noheader", "--format=" + "|".join(fields.values()))
        rows = [dict(zip(fields, line.split("|"), strict=False)) for line in out.stdout.splitlines()]
        return sorted(rows, key=lambda row: int(row["id"]))

    def logs(self, tail: int = 4000) -> str:
        if self.root is None:
            return ""
        text = []
        for path in sorted((self.root / "log").glob("*")):
            text.append(f"--- {path.name}\n{path.read_text(errors='replace')[-tail:]}")
        return "\n".join(text)

    # -- stopping --------------------------------------------------------------------
    def stop(self) -> None:
        """Cancel every job, stop the daemons by their process ids, end the processes
        the jobs left, remove the folder."""
        if "slurmctld" in self.procs and self.procs["slurmctld"].poll() is None:
            self.client("scancel", "--full", "--partition=test", check=False)
            deadline = time.monotonic() + 15
            while time.monotonic() < deadline and any(
                row["state"] in ("PENDING", "RUNNING", "COMPLETING") for row in self._jobs_quiet()
            ):
                time.sleep(0.2)
        for name in reversed(DAEMONS):
            if name in self.procs:
                self._end(self.procs.pop(name))
        for pid in self.leftover_processes():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        if self.root is not None:
            shutil.rmtree(self.root, ignore_errors=True)

    def _jobs_quiet(self):
        try:
            return self.jobs()
        except (subprocess.SubprocessError, OSError):
            return []

    @staticmethod
    def _end(proc: subprocess.Popen) -> None:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(15)

    def leftover_processes(self) -> list[int]:
        """Processes with this cluster's SLURM_CONF in their environment (slurmstepd and
        what it started), other than this one."""
        mark = f"SLURM_CONF={self.conf}".encode() + b"\0"
        found = []
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit() and int(entry.name) != os.getpid():
                try:
                    if mark in (entry / "environ").read_bytes():
                        found.append(int(entry.name))
                except OSError:
                    pass
        return found
