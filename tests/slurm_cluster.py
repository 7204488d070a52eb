"""A real one-node SLURM cluster on 127.0.0.1 for tests (munge + slurmctld + slurmd from Debian's packages).

Recipe and gotchas: ../shared/notes/slurm.md. Everything lives in one state dir; the config must sit at
/etc/slurm/slurm.conf (the executor plugin's job step strips SLURM_CONF before its inner srun), so an existing
file there is moved aside and restored on stop. Daemons are stopped by the PIDs in their PID files, never by name.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

PACKAGES = ["slurmctld", "slurmd", "slurm-client", "munge"]
BINARIES = ["munged", "slurmctld", "slurmd", "sinfo", "sbatch", "squeue", "scancel", "srun"]
SLURM_CONF = Path("/etc/slurm/slurm.conf")
PORTS = (6817, 6818)  # slurmctld, slurmd


class Unavailable(RuntimeError):
    """SLURM cannot run here (the reason is the message)."""


def _which(name: str) -> str | None:
    return shutil.which(name) or next(
        (str(Path(d, name)) for d in ("/usr/sbin", "/usr/bin") if Path(d, name).exists()), None
    )


def missing_binaries() -> list[str]:
    return [b for b in BINARIES if _which(b) is None]


def ensure_installed(timeout_s: float = 300) -> None:
    """apt-get install the Debian packages when a binary is missing (root only), bounded by ``timeout_s``."""
    if not missing_binaries():
        return
    if os.geteuid() != 0:
        raise Unavailable(f"SLURM binaries missing ({', '.join(missing_binaries())}) and not root to install them")
    if not shutil.which("apt-get"):
        raise Unavailable("SLURM binaries missing and no apt-get to install them")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    deadline = time.monotonic() + timeout_s
    for cmd in (
        ["apt-get", "update", "-qq"],
        ["apt-get", "install", "-y", "-qq", "--no-install-recommends", *PACKAGES],
    ):
        left = deadline - time.monotonic()
        try:
            r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=max(left, 1))
        except subprocess.TimeoutExpired:
            raise Unavailable(f"`{' '.join(cmd)}` did not finish within {timeout_s:.0f} s") from None
        if r.returncode:
            raise Unavailable(f"`{' '.join(cmd)}` failed: {(r.stderr or r.stdout).strip()[-500:]}")
    if missing_binaries():
        raise Unavailable(f"still missing after install: {', '.join(missing_binaries())}")


def _port_busy(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


def _mem_mb() -> int:
    with open("/proc/meminfo") as f:
        for line in f:
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) // 1024
    return 4000


class Cluster:
    """``with Cluster() as c: ...`` starts munge, slurmctld and slurmd; leaving stops them (by PID)."""

    def __init__(self, cpus: int | None = None, mem_mb: int | None = None, partition: str = "debug"):
        self.host = socket.gethostname()
        self.cpus = cpus or max(1, min(os.cpu_count() or 1, 2))  # what the machine really has (CI: 2)
        self.mem_mb = mem_mb or max(1000, min(_mem_mb() // 2, 8000))
        self.partition = partition
        self.state: Path | None = None
        self._conf_backup: Path | None = None
        self._conf_installed = False
        self._pidfiles: list[Path] = []

    # -- lifecycle -----------------------------------------------------------------------------------
    def __enter__(self) -> Cluster:
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self, timeout_s: float = 60) -> None:
        if os.geteuid() != 0:
            raise Unavailable("starting slurmctld/slurmd/munged needs root")
        busy = [p for p in PORTS if _port_busy(p)]
        if busy:
            raise Unavailable(f"ports {busy} already in use (another SLURM running?)")
        try:
            addr = socket.gethostbyname(self.host)
        except OSError:
            addr = ""
        if not addr.startswith("127."):
            raise Unavailable(f"hostname {self.host!r} does not resolve to a loopback address ({addr or 'no address'})")
        # under /tmp with 0755 parents: munged runs as the munge user and must reach its socket dir
        self.state = Path(tempfile.mkdtemp(prefix="frng-slurm-"))
        self.state.chmod(0o755)
        S = self.state
        for d in ("munge", "state", "spool", "log", "run"):
            (S / d).mkdir()
        self._start_munge()
        self._write_conf()
        self._pidfiles += [S / "run" / "slurmctld.pid", S / "run" / "slurmd.pid"]
        self._run([_which("slurmctld"), "-c"])
        self._run([_which("slurmd"), "-N", self.host])
        self.wait_idle(timeout_s)

    def _run(self, cmd: list, **kw) -> subprocess.CompletedProcess:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=60, **kw)
        if r.returncode:
            raise RuntimeError(
                f"{' '.join(map(str, cmd))} failed ({r.returncode}): {r.stderr or r.stdout}\n{self.logs()}"
            )
        return r

    def _start_munge(self) -> None:
        m = self.state / "munge"
        (m / "munge.key").write_bytes(os.urandom(1024))
        shutil.chown(m, "munge", "munge")
        shutil.chown(m / "munge.key", "munge", "munge")
        m.chmod(0o711)
        (m / "munge.key").chmod(0o400)
        self.munge_socket = m / "munge.socket.2"
        self._pidfiles.append(m / "munged.pid")
        self._run(
            [
                "runuser",
                "-u",
                "munge",
                "--",
                _which("munged"),
                f"--socket={self.munge_socket}",
                f"--key-file={m / 'munge.key'}",
                f"--pid-file={m / 'munged.pid'}",
                f"--log-file={m / 'munged.log'}",
                f"--seed-file={m / 'munged.seed'}",
            ]
        )

    def _write_conf(self) -> None:
        # batch_sched_delay=0: a submitted batch job starts ~0.8 s later instead of ~2.8 s (slurm's default lets
        # batch scheduling wait up to 3 s; the smoke workflow on the cluster is a chain of ~12 such waits)
        S, H = self.state, self.host
        conf = f"""# frng test cluster ({S}); removed when the test ends
ClusterName=frngci
SlurmctldHost={H}(127.0.0.1)
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket={self.munge_socket}
SlurmUser=root
SlurmdUser=root
StateSaveLocation={S}/state
SlurmdSpoolDir={S}/spool
SlurmctldPidFile={S}/run/slurmctld.pid
SlurmdPidFile={S}/run/slurmd.pid
SlurmctldLogFile={S}/log/slurmctld.log
SlurmdLogFile={S}/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SwitchType=switch/none
SchedulerType=sched/backfill
SchedulerParameters=batch_sched_delay=0
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SlurmdParameters=config_overrides
ReturnToService=2
MinJobAge=300
InactiveLimit=0
KillWait=5
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
NodeName={H} NodeAddr=127.0.0.1 CPUs={self.cpus} RealMemory={self.mem_mb} State=UNKNOWN
PartitionName={self.partition} Nodes=ALL Default=YES MaxTime=INFINITE State=UP
"""
        (S / "slurm.conf").write_text(conf)
        SLURM_CONF.parent.mkdir(parents=True, exist_ok=True)
        if SLURM_CONF.exists() or SLURM_CONF.is_symlink():
            self._conf_backup = SLURM_CONF.with_name(f"slurm.conf.frng-backup-{os.getpid()}")
            SLURM_CONF.rename(self._conf_backup)
        SLURM_CONF.symlink_to(S / "slurm.conf")
        self._conf_installed = True

    def wait_idle(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        out = ""
        while time.monotonic() < deadline:
            r = subprocess.run(["sinfo", "-h", "-N", "-o", "%T"], capture_output=True, text=True, timeout=20)
            out = (r.stdout + r.stderr).strip()
            if r.returncode == 0 and out.split() and all(s.rstrip("*") in ("idle", "mixed") for s in out.split()):
                return
            time.sleep(0.5)
        raise RuntimeError(f"SLURM node not idle after {timeout_s} s (sinfo: {out!r})\n{self.logs()}")

    def logs(self) -> str:
        if not self.state:
            return ""
        parts = []
        for f in [*sorted((self.state / "log").glob("*.log")), self.state / "munge" / "munged.log"]:
            if f.exists():
                parts.append(f"--- {f.name} ---\n" + "\n".join(f.read_text(errors="replace").splitlines()[-30:]))
        return "\n".join(parts)

    # -- queries -----------------------------------------------------------------------------------------
    def jobs(self, states: str = "all") -> list[dict]:
        """Jobs the controller knows: [{id, name, state}]."""
        r = subprocess.run(
            ["squeue", "-h", f"--states={states}", "-o", "%i|%j|%T|%k"], capture_output=True, text=True, timeout=20
        )
        rows = [line.split("|") for line in r.stdout.splitlines() if line.strip()]
        return [{"id": r[0], "name": r[1], "state": r[2], "comment": r[3]} for r in rows]

    # -- teardown ----------------------------------------------------------------------------------------
    def stop(self) -> None:
        """Cancel our jobs, then stop slurmd, slurmctld and munged by PID; restore /etc/slurm/slurm.conf."""
        if self._conf_installed:
            ids = [j["id"] for j in self.jobs("PENDING,RUNNING,COMPLETING")] if _port_busy(PORTS[0]) else []
            if ids:
                subprocess.run(["scancel", *ids], capture_output=True, timeout=20)
        for pidfile in reversed(self._pidfiles):  # slurmd, slurmctld, munged
            _kill_pidfile(pidfile)
        self._pidfiles = []
        if self._conf_installed:
            if SLURM_CONF.is_symlink() and self.state and os.readlink(SLURM_CONF) == str(self.state / "slurm.conf"):
                SLURM_CONF.unlink()
            if self._conf_backup and self._conf_backup.exists():
                self._conf_backup.rename(SLURM_CONF)
            self._conf_installed = False
        if self.state and self.state.exists():
            shutil.rmtree(self.state, ignore_errors=True)
        self.state = None


def _kill_pidfile(pidfile: Path, timeout_s: float = 15) -> None:
    try:
        pid = int(pidfile.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return
    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.2)
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
