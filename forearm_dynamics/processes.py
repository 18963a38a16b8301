"""Child processes: a loopback-only ROS environment, start, log, wait, stop by PID.

The one process toolkit of the repository: the demo, the benchmarks (benchmarks/) and the
tests (test/rosproc.py) start every node through `Child`.

- `ros_env`: every child gets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and the caller's own
  ROS_DOMAIN_ID (never 0, everyone's default); ROS/RMW/Fast DDS variables of the caller are
  not inherited, only what the caller passes explicitly (e.g. a Fast DDS profile).
- `Child`: output goes to files (a chatty child never blocks on a full pipe); it is stopped
  by its own PID only: SIGINT, then SIGKILL if it hangs. Never by name. It starts with
  SIGINT at its default action even when the caller ignores SIGINT (`popen`).
(CPU and memory samples from /proc, which only benchmarks and tests take: benchmarks/procstat.py.)
- `lease_domain`: a ROS domain id no other process on this machine holds through it (an
  flock per id), so two test sessions run at once never share a domain by chance;
  `claim_domain`: the demo's and benchmarks' domain, moved when another run holds it.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

#: The venv's (or colcon install's) console scripts sit next to its python.
BIN = Path(sys.executable).parent
_NOT_INHERITED = ("ROS_", "RMW_", "FASTRTPS", "FASTDDS", "LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP")


#: native_stacks: frames per thread, and the most characters of the whole
NATIVE_FRAMES = 20
NATIVE_CHARS = 30_000


def native_stacks(pid: int, timeout: float = 60.0) -> str:
    """Every thread's native stack of process `pid`, main thread first, by gdb where it is
    installed ("" where not): a process blocked inside C code (a DDS call, rcl's shutdown)
    shows in its Python stacks only as the line that made the call. A test's torque_node
    and trajectory_publisher, stopped beside a second suite, each once hung past 60 s after
    SIGINT, the second in rclpy's _logging_fini (rcl_logging_fini, in C)."""
    gdb = shutil.which("gdb")
    if gdb is None:
        return ""
    try:
        done = subprocess.run([gdb, "-p", str(pid), "-batch", "-nx", "-ex",
                               f"thread apply all bt {NATIVE_FRAMES}"],
                              capture_output=True, text=True, timeout=timeout, check=False)
    except (subprocess.TimeoutExpired, OSError) as exc:
        return f"\nnative stacks: gdb failed: {exc}"
    threads: list[list[str]] = []
    for line in done.stdout.splitlines():
        if line.startswith("Thread "):
            threads.append([line])
        elif line.startswith("#") and threads:
            threads[-1].append(line[:200])
    text = "\n".join("\n".join(t) for t in reversed(threads))  # gdb lists the main thread last
    return f"\nnative stacks (gdb, {len(threads)} threads):\n{text[:NATIVE_CHARS]}"


def ros_env(domain: int, log_dir: Path | str, extra: dict[str, str] | None = None) -> dict[str, str]:
    """Environment of a child node: loopback DDS in `domain`, wheel bootstrap not inherited."""
    if not 0 < domain < 233:
        raise ValueError(f"ROS_DOMAIN_ID must be 1..232 (0 is everyone's default), got {domain}")
    env = {k: v for k, v in os.environ.items() if not k.startswith(_NOT_INHERITED)}
    env.update(
        ROS_DOMAIN_ID=str(domain),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        ROS_LOG_DIR=str(log_dir),
        HOME=os.environ.get("HOME") or tempfile.gettempdir(),
        PYTHONUNBUFFERED="1",
        RCUTILS_COLORIZED_OUTPUT="0",
    )
    env.update(extra or {})
    return env


def rtps_port(domain: int, participant: int | None = None, user: bool = False) -> int:
    """A UDP port RTPS listens on (DDS-RTPS 2.x, 9.6.1.1; Fast DDS's defaults PB 7400, DG
    250, PG 2): discovery multicast PB + DG·domain (participant None), discovery unicast
    + 10 + PG·participant, user-data unicast (`user`) + 11 + PG·participant. Fast DDS
    numbers a participant's shared-memory data port (/dev/shm/fastrtps_port<N>) the same
    as its user-data unicast port."""
    base = 7400 + 250 * domain
    if participant is None:
        return base
    return base + (11 if user else 10) + 2 * participant


@dataclass
class DomainLease:
    """A ROS domain id held by this process until release() or its exit (the kernel drops an
    flock with its process, so a killed session frees its domains by itself)."""

    domain: int
    _fd: int | None = None

    @property
    def exclusive(self) -> bool:
        """False when every id of the range was held and this one is shared."""
        return self._fd is not None

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the lock
            self._fd = None


def lease_domain(lo: int, hi: int, start: int | None = None, lock_dir: Path | None = None) -> DomainLease:
    """The first free id of lo..hi, trying from lo + start % (hi - lo + 1) (default: the pid).

    Free = no other process holds it through lease_domain (a lock file per id in the temp
    directory). When all are held the start id is returned, shared (`exclusive` False):
    sharing a domain is slower, not wrong, for nodes in their own namespaces.
    """
    ids = range(lo, hi + 1)
    first = (os.getpid() if start is None else start) % len(ids)
    lock_dir = lock_dir or Path(tempfile.gettempdir()) / "forearm_dynamics_domains"  # a test: its own
    for i in range(len(ids)):
        domain = ids[(first + i) % len(ids)]
        try:
            lock_dir.mkdir(exist_ok=True)
            fd = os.open(lock_dir / f"{domain}.lock", os.O_RDWR | os.O_CREAT, 0o666)  # not inherited
        except OSError:  # no usable temp directory: share, as when all are held
            break
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        return DomainLease(domain, fd)
    return DomainLease(ids[first])


def claim_domain(wanted: int, prog: str, lock_dir: Path | None = None) -> DomainLease:
    """`wanted`, or the next id of its range that no other run on this machine holds (a
    second `make demo`, a test session), said in one line on stderr. Ranges: 1..101 and
    215..232 (DDS ports outside Linux's ephemeral range) and 102..214 (the tests' own).
    Hold the lease for the run."""
    if not 0 < wanted < 233:
        raise ValueError(f"ROS domain must be 1..232 (0 is everyone's default), got {wanted}")
    lo, hi = next(r for r in ((1, 101), (102, 214), (215, 232)) if r[0] <= wanted <= r[1])
    lease = lease_domain(lo, hi, wanted - lo, lock_dir)
    if lease.domain != wanted:
        print(f"{prog}: ROS domain {wanted} is in use by another forearm_dynamics run on this "
              f"machine; using {lease.domain}", file=sys.stderr, flush=True)
    elif not lease.exclusive:
        print(f"{prog}: every ROS domain of {lo}..{hi} is in use; sharing {wanted}",
              file=sys.stderr, flush=True)
    return lease


def _new_file(directory: Path, stem: str, suffix: str) -> Path:
    """directory/stem.suffix, or stem-2.suffix, ... : never another child's log."""
    for i in range(1, 10_000):
        path = directory / (f"{stem}{suffix}" if i == 1 else f"{stem}-{i}{suffix}")
        try:
            os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
        except FileExistsError:
            continue
        return path
    raise FileExistsError(f"no free log name for {stem} in {directory}")


def popen(argv: list[str], **kwargs) -> subprocess.Popen:
    """Popen, the child's SIGINT at its default action (Ctrl-C ends it) even where this
    process ignores SIGINT, so that stop()'s SIGINT reaches every child.

    A command started with `&` by a non-interactive shell (`make test &` in a script, CI
    runners, nohup-style wrappers) has SIGINT ignored (POSIX), and an ignored signal stays
    ignored across fork and exec: every child then ignored stop()'s SIGINT until the kill
    timeout (a plain Python child for good, a ROS node until rclpy.init installs its own
    handler), which looked like a slow machine. A signal that is caught is reset to its
    default action by exec: so while starting the child, this process catches SIGINT (and
    drops it, as ignoring it would have). Off the main thread (where Python cannot set a
    handler), a small Python step resets it and execs the command (same PID).
    """
    if signal.getsignal(signal.SIGINT) != signal.SIG_IGN:
        return subprocess.Popen(argv, **kwargs)
    if threading.current_thread() is not threading.main_thread():
        return subprocess.Popen([sys.executable, "-c", _EXEC_WITH_DEFAULT_SIGINT, *argv], **kwargs)
    signal.signal(signal.SIGINT, _drop)
    try:
        return subprocess.Popen(argv, **kwargs)
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _drop(_signum, _frame) -> None:
    """SIGINT while a child starts, in a process that ignores SIGINT: ignored still."""


#: Reset SIGINT to its default action, then become argv (same PID): preexec_fn is unsafe
#: with threads, and this path is for callers off the main thread.
_EXEC_WITH_DEFAULT_SIGINT = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
                             "os.execvp(sys.argv[1], sys.argv[1:])")


class Child:
    """One started process, its output in `log` (stdout and stderr, or `log` and `err_log`).

    `cpus`: CPU affinity of the process and every thread it starts (None: any).
    `fifo`: SCHED_FIFO priority of the process and every thread it starts (0: normal).
    `split_stderr`: stderr to its own file `err_log` (tests read the two apart).
    """

    def __init__(self, name: str, argv: list[str], env: dict[str, str], log_dir: Path,
                 cpus: set[int] | None = None, split_stderr: bool = False, fifo: int = 0):
        self.name = name
        self.argv = list(argv)
        log_dir.mkdir(parents=True, exist_ok=True)
        self.log = _new_file(log_dir, name, ".log")
        self.err_log = self.log.with_suffix(".err") if split_stderr else None
        with self.log.open("wb") as out:
            if self.err_log is None:
                self.proc = popen(argv, env=env, stdout=out, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL)
            else:
                with self.err_log.open("wb") as err:
                    self.proc = popen(argv, env=env, stdout=out, stderr=err,
                                       stdin=subprocess.DEVNULL)
        if cpus:
            # Popen returns once exec succeeded: the child has one thread, and every thread
            # it starts later (rclpy, Fast DDS) inherits this affinity.
            os.sched_setaffinity(self.proc.pid, cpus)
        if fifo:  # as for cpus: inherited by every thread it starts
            os.sched_setscheduler(self.proc.pid, os.SCHED_FIFO, os.sched_param(fifo))

    @classmethod
    def script(cls, name: str, ros_args: list[str], env: dict[str, str], log_dir: Path,
               label: str | None = None, cpus: set[int] | None = None,
               split_stderr: bool = False, fifo: int = 0) -> Child:
        """A console script of this venv with `--ros-args *ros_args` (if any)."""
        argv = [str(BIN / name)] + (["--ros-args", *ros_args] if ros_args else [])
        return cls(label or name, argv, env, log_dir, cpus, split_stderr, fifo)

    @classmethod
    def module(cls, name: str, module: str, args: list[str], env: dict[str, str],
               log_dir: Path, cpus: set[int] | None = None, fifo: int = 0) -> Child:
        """`python -m module *args` with this interpreter."""
        return cls(name, [sys.executable, "-m", module, *args], env, log_dir, cpus, fifo=fifo)

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def running(self) -> bool:
        return self.proc.poll() is None

    def stdout(self) -> str:
        """stdout (and stderr unless split) so far."""
        try:
            return self.log.read_text(errors="replace")
        except OSError:
            return ""

    def stderr(self) -> str:
        """stderr so far ('' unless split: it is in stdout())."""
        if self.err_log is None:
            return ""
        try:
            return self.err_log.read_text(errors="replace")
        except OSError:
            return ""

    def text(self) -> str:
        """Everything the process printed so far."""
        return self.stdout() + self.stderr()

    def wait_for(self, text: str, timeout: float, *, regex: bool = False) -> bool:
        """True once `text` is in the output (with `regex`, a match of that pattern); False
        on timeout or exit without it."""
        found = re.compile(text).search if regex else (lambda out: text in out)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if found(self.text()):
                return True
            if not self.running():
                return bool(found(self.text()))
            time.sleep(0.05)
        return False

    def wait(self, timeout: float) -> int | None:
        """The exit code, or None if it still runs after `timeout` s."""
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def stacks(self, python: bool, native: bool = True) -> str:
        """Where this running process is: with `python` (one of our nodes, nodes/common.run)
        its threads' Python stacks into its output (SIGUSR1, then a second to print them; any
        other process would die of it), and with `native` every thread's native stack,
        returned (native_stacks; "" once the process has exited)."""
        if python and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGUSR1)
            time.sleep(1.0)
        return native_stacks(self.proc.pid) if native and self.proc.poll() is None else ""

    def stop(self, sig: int = signal.SIGINT, timeout: float = 15.0, strict: bool = False,
             dump: bool = False) -> int:
        """Signal this process only; SIGKILL if it has not exited after `timeout` s.

        The exit code (-9 after a SIGKILL); with `strict`, a hang raises TimeoutExpired
        once the process is killed (a node that ignores SIGINT is a bug a test must see).
        `dump`: the process is one of our nodes, which print every thread's Python stack on
        SIGUSR1 (nodes/common.run): sent before the kill, so its output says where it hung
        (any other process would die of SIGUSR1 instead of SIGKILL); with `strict`, the
        message also holds its threads' native stacks (native_stacks).
        """
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                native = self.stacks(python=True, native=strict) if dump else ""
                self.proc.kill()
                self.proc.wait(timeout=10)
                if strict:
                    raise subprocess.TimeoutExpired(
                        self.argv, timeout, output=self.text()[-6000:] + native) from None
        return self.proc.returncode
