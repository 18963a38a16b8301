"""What every node shares: a shutdown-safe spin, QoS from parameters, the config topic."""

from __future__ import annotations

import contextlib
import faulthandler
import gc
import signal
import sys
import threading
import time
from collections.abc import Callable

import rclpy
from rclpy.exceptions import NameValidationException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from threadpoolctl import threadpool_limits

from ..exit_codes import OK, USAGE
from ..realtime import make_normal, set_thread_name
from .params import ParameterError

#: Latched topic on which the torque node states its model (kind, body size, joint names).
CONFIG_TOPIC = "torque_node/config"

EXECUTORS = ("events", "single")


def latched_qos(depth: int = 1) -> QoSProfile:
    """Reliable and transient local: a subscriber that joins late still gets the last `depth`."""
    return QoSProfile(
        depth=depth,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


def stream_qos(depth: int = 100, reliable: bool = True) -> QoSProfile:
    return QoSProfile(
        depth=depth,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


#: how often a node looks at its endpoints' match counts (MatchLog; one call costs ~2 µs)
MATCH_POLL_S = 0.1


class MatchLog:
    """Logs a line when an endpoint's count of matched peers changes (polled by a timer).

    Discovery is two one-way exchanges: a writer can count a reader seconds before that
    reader has matched the writer, and what the writer sends meanwhile can be acknowledged
    and never delivered (a loaded test run lost a stream's first 477 samples so). Each side
    logs its own count; a stream that must arrive from its first sample starts once both
    lines are out (docs/ros.md, "Start-up"), as rosbag2's "Subscribed to topic" is waited for.
    """

    def __init__(self, node: Node, count: Callable[[], int], line: Callable[[int], str]):
        self.count, self.line, self._log = count, line, node.get_logger()
        self.n = 0

    def __call__(self) -> None:
        n = self.count()
        if n != self.n:
            self.n = n
            self._log.info(self.line(n))


def make_executor(kind: str = "events"):
    """EventsExecutor measured best at 1 kHz on these wheels; single-threaded as a fallback.

    make bench (section choices, torque_node at 1 kHz): events 15.7 % CPU, latency p50
    0.263 ms; single-threaded 36.1 %, 0.320 ms. The MultiThreadedExecutor is not offered:
    with a timer and a busy subscription it collapses to tens of Hz (docs/design-notes.md,
    "Executors").
    """
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    if kind == "single":
        return rclpy.executors.SingleThreadedExecutor()
    raise ValueError(f"executor must be 'events' or 'single', got {kind!r}")


def spin(node: Node, executor=None, timeout_sec: float = 0.5, done: Future | None = None,
         drain: tuple[float, Callable[[], int]] | None = None) -> None:
    """Spin until SIGINT/SIGTERM, shutdown, or `done` completes.

    EventsExecutor.spin() in these wheels burns a core and ignores SIGINT, so wait on a
    future with a timeout while rclpy.ok(); the context's shutdown wakes the executor.

    The timeout alone does not end a turn: the EventsExecutor of these wheels runs its
    queue until it is empty (EventsQueue::RunUntil checks its deadline only while the
    queue is empty), so a node behind by a backlog stopped only once it had drained it
    (CI: torque_node with qos_depth 10000 at load 9 still running 60 s after SIGINT). So
    the spin waits on `wake`, completed by the node's `done` or by a stop signal; the
    signal's side is a watcher thread (_wake_on_stop), because a signal handler must not
    take the Future's lock, which the main thread may hold when the signal comes. The
    queue then stops after the callback in progress.

    drain (seconds, progress): after a stop signal, the callbacks already queued (messages
    the readers hold: received and acknowledged, not yet taken) run too, one at a time, until
    `progress()` (e.g. messages written) stops moving for DRAIN_IDLE_S or the seconds are up.
    A stopped recorder thus keeps what its readers held at the signal (the CI loss of 3 000
    of 3 001 this was first written for turned out to be the stream's first sample, a late
    match: MatchLog); a torque node's backlog is not drained (its answers
    are late).
    """
    executor = executor or make_executor()
    wake = Future()
    if done is not None:
        done.add_done_callback(lambda _f: wake.set_result(None))
    ended = threading.Event()
    watcher = threading.Thread(target=_wake_on_stop, args=(wake, ended), name="stop_watch",
                               daemon=True)
    watcher.start()
    executor.add_node(node)
    try:
        while rclpy.ok() and not wake.done() and not STOP.requested:
            executor.spin_until_future_complete(wake, timeout_sec=timeout_sec)
        if drain is not None and STOP.requested and rclpy.ok():
            _drain(executor, *drain)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # SIGINT/SIGTERM shut the context down while a callback was publishing: rcl then
        # raises "context is invalid". That is a normal exit; anything else is a bug.
        if rclpy.ok():
            raise
    finally:
        ended.set()
        try:
            executor.remove_node(node)
        except Exception:  # noqa: BLE001, S110 - the context may already be shut down
            pass


#: a drain after a stop ends when the node's progress has not moved for this long (s)
DRAIN_IDLE_S = 0.05


def _drain(executor, seconds: float, progress: Callable[[], int]) -> None:
    """Run callbacks until `progress()` has not moved for DRAIN_IDLE_S (wall time: a turn
    that ran a timer's callback, not a message's, is no sign the readers are empty) or
    `seconds` are up."""
    start = idle_since = time.monotonic()
    last = progress()
    while rclpy.ok():
        executor.spin_once(timeout_sec=DRAIN_IDLE_S / 5)
        now, t = progress(), time.monotonic()
        if now != last:
            last, idle_since = now, t
        elif t - idle_since >= DRAIN_IDLE_S:
            return
        if t - start >= seconds:
            return


#: how often the stop watcher looks at STOP (s): the stop's latency beyond the callback
#: in progress; a wake-up costs microseconds of the GIL
_STOP_POLL_S = 0.05


def _wake_on_stop(wake: Future, ended: threading.Event) -> None:
    """Complete `wake` once SIGINT/SIGTERM was noted (STOP), until the spin has ended.
    A helper thread: named, and at normal priority whatever the node's (docs/realtime.md)."""
    set_thread_name("stop_watch")
    make_normal()
    while not ended.wait(_STOP_POLL_S):
        if STOP.requested:
            wake.set_result(None)
            return


class _Stop:
    """Whether SIGINT/SIGTERM came (and how many): see hold_stop_signals()."""

    requested = False
    count = 0


STOP = _Stop()


def _on_stop_signal(signum, frame) -> None:  # noqa: ARG001 - the signal module's signature
    STOP.requested = True
    STOP.count += 1


def hold_stop_signals() -> None:
    """SIGINT and SIGTERM only request a stop: they never raise, and never shut the context
    down under a running callback.

    rclpy's own handlers (rclpy.init's default) shut the context down from the signal and
    then let Python's SIGINT handler raise KeyboardInterrupt wherever the main thread is.
    Under the EventsExecutor that is inside callbacks called from C++: a KeyboardInterrupt
    in a service callback cannot be carried back out by pybind11 and the process aborts
    ("terminate called after throwing ... error_already_set", exit -6; torque_node did in 4
    of 6 stops under `ros2 launch`, which forwards SIGINT while the terminal or `timeout`
    signals the group: two signals), and a subscription callback publishing on the shut
    context is logged as [FATAL] with a traceback. So run() starts rclpy without its
    handlers and this one only notes the stop; spin() ends after the callback in progress, and
    run() then shuts the context down and finishes the node however many signals came.
    """
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, _on_stop_signal)


def run(make_node: Callable[[], Node], name: str, args: list[str] | None = None) -> int:
    """Create the node, spin it, clean up: the one main loop of every node.

    Exit codes (exit_codes.py): OK after SIGINT/SIGTERM (rclpy's signal handlers shut the
    context down, which ends spin()), also during start-up; USAGE for a refused parameter
    or unusable --ros-args; otherwise what the node says. The node may set
    `executor_kind` and `done` (a Future) to steer the spin, and define `finish() -> int`
    (called after the spin, e.g. to close a file) or an `exit_code` attribute, and
    `settle_on_stop()` (after a stop's spin, before the context goes: e.g. wait for acks).

    rcl failures reach Python as rclpy's RCLError, a RuntimeError: caught by that public
    base class (the class itself lives in rclpy's private extension module).
    """
    hold_stop_signals()
    # `kill -USR1 <pid>`: every thread's Python stack on stderr (where a node hangs)
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:  # an unreadable --params-file or malformed --ros-args
        print(f"[ERROR] [{name}]: invalid arguments: {exc}", file=sys.stderr)
        return USAGE
    if STOP.requested:  # SIGINT/SIGTERM during start-up: a stop, nothing done yet
        rclpy.try_shutdown()
        return OK
    node = None
    try:
        try:
            node = make_node()
        except ParameterError as exc:
            rclpy.logging.get_logger(name).error(str(exc))
            destroy_half_made(exc)
            return USAGE
        except (KeyboardInterrupt, ExternalShutdownException) as exc:
            destroy_half_made(exc)
            return OK  # stopped during start-up (the node left its files complete)
        except Exception as exc:
            if not rclpy.ok():  # SIGINT/SIGTERM during start-up: rcl calls fail, a normal stop
                destroy_half_made(exc)
                return OK
            if not isinstance(exc, (RuntimeError, NameValidationException)):
                raise
            rclpy.logging.get_logger(name).error(f"cannot start: {exc}")  # e.g. a remap clash
            destroy_half_made(exc)
            return USAGE
        executor = make_executor(getattr(node, "executor_kind", "events"))
        # One BLAS thread: a node's linear algebra is 3x3 to 20x20, where OpenBLAS threads
        # only cost: after each threaded call they spin-wait ~0.1 s for more work, a whole
        # core on a 2-core machine (measured: torque_node at 105 % CPU with the Kalman
        # filter's occasional Riccati solves, 21 % without).
        threadpool_limits(1, user_api="blas")
        # Start-up objects (modules, model, messages) live as long as the process: freeze
        # them so a full garbage collection never walks them while streaming at 1 kHz.
        gc.collect()
        gc.freeze()
        # Real-time scheduling now: the middleware's threads exist (docs/realtime.md).
        start_realtime = getattr(node, "start_realtime", None)
        if callable(start_realtime):
            start_realtime()
        on_serving = getattr(node, "on_serving", None)
        if callable(on_serving):
            on_serving()
        if not STOP.requested:  # (a stop during start-up: the node made, nothing to serve)
            try:
                spin(node, executor, done=getattr(node, "done", None),
                     drain=getattr(node, "drain_on_stop", None))
            except (KeyboardInterrupt, ExternalShutdownException):
                pass
        if STOP.requested:  # out of the executor: the context goes (helper threads see it)
            settle = getattr(node, "settle_on_stop", None)
            if callable(settle):  # while the context lives, e.g. a writer's last repairs
                settle()
            rclpy.try_shutdown()
        try:
            return _finish(node)
        except KeyboardInterrupt:  # a second SIGINT before the first lines of _finish held it
            return _finish(node)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def destroy_half_made(exc: BaseException) -> None:
    """Destroy, in rclpy's order, the node whose constructor raised `exc` (found as `self` in
    its traceback's frames), before the exception is dropped.

    A constructor that refuses a parameter raises after rclpy's Node.__init__ made the rcl
    node, its parameter services and its /rosout publisher. Nothing else refers to that
    half-made node: when run() drops the exception, Python frees it and its entities in
    whatever order its references go, the rmw participant included, with discovery of the
    nodes that started beside it still under way. In CI one of 150 refused starts (eight at
    a time in one domain) hung there for 180 s after its error line (the stack at the end of
    run()'s except clause). destroy_node() is the order every normal stop uses (entities,
    then the node), and what rclpy asks for (ros2/rclpy#456: destroy a node's objects before
    the node, explicitly, not by garbage collection)."""
    tb = exc.__traceback__
    while tb is not None:
        node = tb.tb_frame.f_locals.get("self")
        if isinstance(node, Node):
            with contextlib.suppress(AttributeError, RuntimeError):  # Node.__init__ failed:
                node.destroy_node()  # its parts missing (AttributeError) or not made (rcl's)
            return
        tb = tb.tb_next


def _finish(node: Node) -> int:
    """The node's finish() (e.g. close a file) with SIGINT/SIGTERM ignored meanwhile: a second
    signal (an impatient Ctrl-C, a supervisor's SIGTERM after SIGINT) must not cut it short;
    finish() is idempotent, so an interrupted call is simply made again (run())."""
    finish = getattr(node, "finish", None)
    if not callable(finish):
        return getattr(node, "exit_code", OK)
    held = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return finish()
    finally:
        for s, handler in held.items():
            signal.signal(s, handler)


def main_for(make_node: Callable[[], Node], name: str) -> None:
    """Console-script entry point: run the node and exit with its code."""
    try:
        code = run(make_node, name, sys.argv)
    except KeyboardInterrupt:  # SIGINT before rclpy's handlers exist: a stop, nothing done yet
        code = OK
    # Done: a late SIGINT/SIGTERM is ignored from here. At exit Python sets a signal it
    # handles in Python back to SIG_DFL, and a second signal 0.1 s after the first (ros2
    # launch and a terminal both) then killed a node that had stopped cleanly (exit -2).
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, signal.SIG_IGN)
    sys.exit(code)
