"""Launch = data + runner: run a launch file's node graph, each node in a process of its own.

The launch file and its validation are :mod:`hil_bridge.launch.spec` (its names are importable
from here too); this module runs a :class:`LaunchSpec`, watches it and judges the run.

Each entry implements the *launchable* contract:

- ``Cls(name, *, bus, **params)``; ``start()`` (non-blocking); ``stop()`` (idempotent, joins
  its threads); ``stats() -> dict``;
- optionally ``finished() -> bool | None``: its work is done (a server that reached its
  ``stop_after_s`` and answered every ping; None: it has no end of its own). A run started
  with ``until_finished`` ends (``stopped_by`` ``"finished"``) once every launchable that has
  an end says it is finished;
- optionally ``failure(*, final: bool = False) -> str | None``: why it failed, naming the place
  (``"tick loop: RuntimeError: ..."``), or None. The runner asks it while the run goes (every
  :data:`FAILURE_POLL_S`) and ends the run at the first answer; at the end of the run, before
  anything is stopped, with ``final=True`` (a fault the launchable declared recoverable and that
  never recovered is then a failure too), and once more after its ``stop()`` (a failure while
  stopping, e.g. a recording that could not be committed). A ``failure()`` without the
  ``final`` parameter is called without it. The project's launchables answer from their
  :class:`hil_bridge.bus.faults.Faults`, to which their callbacks, timers and threads report.

A node whose constructor or ``start()`` raises fails the run the same way (the nodes already
built are stopped in reverse order, nothing else starts); only a node that refuses its params
(``ConfigError``, or a ``TypeError`` for an unknown one) raises, as the launch file's error.

**Processes or threads.** On a bus that crosses processes (``tcp://``, ``ipc://``) in a
numbered domain, every *container* (by default each node; nodes naming one ``container:``
share it) runs in a host process of its own (:mod:`hil_bridge.launch.process`,
:mod:`hil_bridge.launch.host`): all hosts import their nodes' modules at once, then construct
their nodes in the file's order, then start them, as the threads runner does. What used to tie
nodes to one process crosses processes now: the domain's virtual CAN bus is loopback multicast
(:mod:`drivers.can.loopback`), the sonar head's pty is a path. A host that dies fails its nodes
(the exit code or signal and its last log lines); hosts die with the runner. A ``mem://`` bus or
a private domain (the pytest fixture's) keeps every node a thread of this process
(``processes=False``, ``echoloop launch --threads``), through the same launchable contract.

Precedence of settings: CLI arguments (``--param``, ``--duration``, ``--record``, ``--bus``) >
the file > the domain's defaults. The run's domain (``run(domain=...)``, ``--domain``, else
``ECHOLOOP_DOMAIN``) is active while the nodes are constructed, so every default port, pty link
and virtual CAN channel a node picks is the domain's (:mod:`hil_bridge.bus.domain`).

**Exit status**: :mod:`hil_bridge.launch.summary` (:func:`judge`, one place).
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import logging
import signal
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import FrameType
from typing import Any, Literal, Protocol, runtime_checkable

from hil_bridge.bus.domain import Domain, resolve, use
from hil_bridge.bus.proxy import proxy_for
from hil_bridge.bus.transport import sync_open
from hil_bridge.launch.expect import Expectation, parse_expectations
from hil_bridge.launch.monitor import BusMonitor
from hil_bridge.launch.process import ContainerProcess, NodeStartError
from hil_bridge.launch.spec import (
    PROJECT_PACKAGES,
    LaunchSpec,
    NodeSpec,
    check_duration,
    check_entry_module,
    compose_lockstep,
    launch_proxy,
    load,
    node_params,
    parse_param_overrides,
    resolve_entry,
    select_nodes,
    with_speed,
)
from hil_bridge.launch.summary import (
    EXIT_AFTER_RUN,
    EXIT_DISCONNECTED,
    EXIT_EXPECT,
    EXIT_FAILED,
    EXIT_OK,
    Failure,
    RunSummary,
    collect_links,
    judge,
)
from hil_bridge.priority import RunThreads, can_realtime
from sim_core.config import ConfigError

__all__ = [
    "EXIT_AFTER_RUN",
    "EXIT_DISCONNECTED",
    "EXIT_EXPECT",
    "EXIT_FAILED",
    "EXIT_OK",
    "FAILURE_POLL_S",
    "PROJECT_PACKAGES",
    "BusMonitor",
    "Failure",
    "LaunchSpec",
    "Launchable",
    "NodeSpec",
    "RunSummary",
    "check_duration",
    "check_entry_module",
    "collect_links",
    "failure_of",
    "finished_of",
    "judge",
    "load",
    "parse_param_overrides",
    "processes_for",
    "resolve_entry",
    "run",
]

log = logging.getLogger(__name__)


#: how often (wall s) the runner asks every launchable for its ``failure()`` while the run goes
FAILURE_POLL_S = 0.05
#: seconds the launcher (and each node host) waits for its bus endpoints to be in sync with
#: the proxy before it starts nodes (:func:`~hil_bridge.bus.transport.sync_open`)
SYNC_TIMEOUT_S = 30.0


@runtime_checkable
class Launchable(Protocol):
    """What every launch entry implements (constructor ``Cls(name, *, bus, **params)``); the
    optional ``failure(*, final=False)`` is described in the module docstring."""

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def stats(self) -> dict[str, Any]: ...


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def failure_of(obj: Any, *, final: bool = False) -> str | None:
    """A launchable's own account of failing: its optional ``failure(*, final=False)``
    (one without ``final`` is called without it)."""
    report = getattr(obj, "failure", None)
    if not callable(report):
        return None
    if final:
        try:
            takes_final = "final" in inspect.signature(report).parameters
        except (TypeError, ValueError):
            takes_final = False
        if takes_final:
            return report(final=True)
    return report()


def finished_of(obj: Any) -> bool | None:
    """A launchable's optional ``finished()``: None when it has none (or no end of its own)."""
    report = getattr(obj, "finished", None)
    if not callable(report):
        return None
    answer = report()
    return None if answer is None else bool(answer)


class _Watch:
    """The run's launchables by name and what failed among them (``failed``: ``(source,
    reason)`` for :func:`judge`, at most one ``failure()`` account per launchable)."""

    def __init__(self) -> None:
        self.items: list[tuple[str, Any]] = []
        self.failed: list[tuple[str, str]] = []
        self._accounted: set[str] = set()

    def fail(self, name: str, reason: str) -> None:
        self.failed.append((name, reason))

    def ask(self, name: str, obj: Any, *, final: bool = False) -> str | None:
        """Ask ``obj`` for its ``failure()`` (once it answered, never again); note it."""
        if name in self._accounted:
            return None
        try:
            reason = failure_of(obj, final=final)
        except Exception as exc:  # a broken failure() is a failure, not a crash of the runner
            log.exception("%s: failure() raised", name)
            reason = f"failure() raised {_describe(exc)}"
        if reason:
            self._accounted.add(name)
            self.fail(name, reason)
        return reason or None

    def all_finished(self) -> bool:
        """Whether every launchable with an end of its own says it is finished (and one
        has)."""
        answers = []
        for name, obj in self.items:
            try:
                answers.append(finished_of(obj))
            except Exception as exc:  # a broken finished() is that launchable's failure
                log.exception("%s: finished() raised", name)
                self.fail(name, f"finished() raised {_describe(exc)}")
                return False
        ends = [a for a in answers if a is not None]
        return bool(ends) and all(ends)

    def poll(self) -> tuple[str, str] | None:
        """The first launchable that says it failed, as ``(name, reason)``, or None."""
        for name, obj in self.items:
            reason = self.ask(name, obj)
            if reason is not None:
                return name, reason
        return None

    def stop_and_collect(self, name: str, obj: Any) -> dict[str, Any]:
        """Stop one launchable, take its stats and ask it once more whether it failed (while
        stopping); whatever goes wrong is noted."""
        stats: dict[str, Any] = {}
        for step in ("stop", "stats"):
            try:
                if step == "stop":
                    obj.stop()
                else:
                    stats = obj.stats()
            except Exception as exc:  # one broken node must not hide the others' results
                log.exception("%s: %s() raised", name, step)
                self.fail(name, f"{step}() raised {_describe(exc)}")
        self.ask(name, obj)
        return stats


class _StopFlag:
    """A stop event plus the reason; set from signal handlers or the duration timer."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.reason = "duration"

    def set(self, reason: str) -> None:
        if not self.event.is_set():
            self.reason = reason
            self.event.set()


def _instantiate(
    spec: LaunchSpec, bus: str, watch: _Watch, made: list[tuple[str, Any]], *, overwrite: bool
) -> bool:
    """Construct every node into ``made`` (so the caller can stop those built before a failure);
    False when a constructor raised (noted in ``watch``; the nodes after it are not built).

    A node that refuses its params (``ConfigError``; an unknown param's ``TypeError``) raises
    ConfigError. With ``overwrite``, nodes whose constructor takes an ``overwrite`` parameter
    (those that write files: captures, CAN logs) get ``overwrite=True`` unless their params set
    it."""
    for i, node in enumerate(spec.nodes):
        cls = resolve_entry(node.entry, where=f"nodes[{i}].entry",
                            allow_modules=spec.allow_modules)
        params = node_params(node, cls, overwrite=overwrite)
        try:
            obj = cls(node.name, bus=bus, **params)
        except TypeError as exc:
            raise ConfigError(f"nodes[{i}] ({node.name}).params: {exc}") from None
        except ConfigError:
            raise
        except Exception as exc:
            log.exception("%s: constructor raised", node.name)
            watch.fail(node.name, f"constructor raised {_describe(exc)}")
            return False
        made.append((node.name, obj))
    return True


def _start(made: Sequence[tuple[str, Any]], watch: _Watch, sync: str | None) -> bool:
    """Start the nodes in order; with ``sync`` (the bus URL of the launch's own proxy), once
    this process's endpoints on it (the recorder's, the monitor's, nodes run as threads) are in
    sync with the proxy. False when one's ``start()`` raised or the endpoints did not get in
    sync (noted in ``watch``; the nodes after it are not started)."""
    late = [] if sync is None else sync_open(SYNC_TIMEOUT_S, url=sync)
    if late:
        watch.fail("launch", f"bus endpoint(s) {', '.join(sorted(set(late)))} not in sync with "
                             f"the proxy after {SYNC_TIMEOUT_S:g} s")
        return False
    for name, obj in made:
        try:
            obj.start()
        except Exception as exc:
            log.exception("%s: start() raised", name)
            watch.fail(name, f"start() raised {_describe(exc)}")
            return False
    return True


def _wait(flag: _StopFlag, watch: _Watch, run_for: float | None,
          stop_event: threading.Event | None, until_finished: bool = False) -> None:
    """Until ``run_for`` seconds passed, a signal, ``stop_event``, a launchable failed, or
    (``until_finished``) every launchable with an end finished."""
    deadline = None if run_for is None else time.monotonic() + run_for
    while not flag.event.is_set():
        if stop_event is not None and stop_event.is_set():
            flag.set("stop_event")
            break
        failed = watch.poll()
        if failed is not None:
            log.error("%s failed (%s): ending the run", *failed)
            flag.set("failure")
            break
        if until_finished and watch.all_finished():
            flag.set("finished")
            break
        remaining = None if deadline is None else deadline - time.monotonic()
        if remaining is not None and remaining <= 0:
            flag.set("duration")
            break
        flag.event.wait(FAILURE_POLL_S if remaining is None else min(FAILURE_POLL_S, remaining))


def _spawn(
    spec: LaunchSpec, bus: str, watch: _Watch, made: list[tuple[str, Any]], *, overwrite: bool,
    domain: Domain, log_dir: Path | None, sync: bool,
) -> bool:
    """Spawn every container's process at once (they import their nodes' modules meanwhile),
    then have each construct its nodes in the order of its first node; ``made`` gets a
    :class:`~hil_bridge.launch.process.RemoteNode` per node, whose ``start()`` starts them.
    False when a container did not come up (noted in ``watch``; the ones after it are killed)."""
    containers: dict[str, list[dict[str, Any]]] = {}
    for i, node in enumerate(spec.nodes):
        cls = resolve_entry(node.entry, where=f"nodes[{i}].entry",
                            allow_modules=spec.allow_modules)
        containers.setdefault(node.container or node.name, []).append(
            {"name": node.name, "entry": node.entry, "realtime": node.realtime,
             "params": node_params(node, cls, overwrite=overwrite)})
    if domain.number is None:
        raise ConfigError(f"{domain} has no number: its nodes cannot be processes")
    procs = [ContainerProcess(key, nodes, bus=bus, domain=domain.number,
                              allow_modules=spec.allow_modules, log_dir=log_dir, sync=sync)
             for key, nodes in containers.items()]
    try:
        for proc in procs:  # every host imports its nodes' modules at once
            proc.spawn()
        for proc in procs:  # and constructs them in the file's order
            try:
                proc.construct()
            except NodeStartError as exc:
                watch.fail(proc.nodes[0]["name"], str(exc))
                return False
            made.extend((n["name"], proc.node(n["name"])) for n in proc.nodes)
    finally:
        for proc in procs:
            if not any(name == proc.nodes[0]["name"] for name, _ in made):
                proc.kill()
    return True


def processes_for(bus: str, domain: Domain) -> bool:
    """Whether a launch on ``bus`` in ``domain`` can run its nodes as processes."""
    return not bus.startswith("mem://") and domain.number is not None


def _warn_no_realtime(spec: LaunchSpec) -> None:
    """One line for the run when the OS refuses ``SCHED_FIFO`` (each node host then notes it
    in its own log only, and its stats' ``scheduling`` says why)."""
    asked = ", ".join(f"{n.name} ({n.realtime})" for n in spec.nodes if n.realtime)
    log.warning("realtime: SCHED_FIFO %d not permitted (ulimit -r %d, no CAP_SYS_NICE): %s run "
                "at normal priority (docs/launch.md, Real time)", spec.realtime, _rtprio_limit(),
                asked)


def _rtprio_limit() -> int:
    import resource

    return int(resource.getrlimit(resource.RLIMIT_RTPRIO)[0])


def run(
    path: str | Path | Mapping[str, Any] | LaunchSpec,
    *,
    params_overrides: Mapping[str, Mapping[str, Any]] | None = None,
    duration: float | None = None,
    record: str | Path | None = None,
    live: bool | None = None,
    bus: str | None = None,
    stop_event: threading.Event | None = None,
    handle_signals: bool = True,
    on_started: Callable[[LaunchSpec], None] | None = None,
    domain: Domain | int | str | None = None,
    expect: Sequence[str | Expectation] = (),
    allow_disconnected: bool = False,
    overwrite: bool = False,
    allow_modules: Sequence[str] = (),
    after_run: Mapping[str, Callable[[RunSummary], object]] | None = None,
    processes: bool | None = None,
    only: Sequence[str] = (),
    skip: Sequence[str] = (),
    log_dir: str | Path | None = None,
    monitor: bool = True,
    realtime: bool = True,
    speed: float | Literal["file"] | None = "file",
    compose: bool = True,
    until_finished: bool = False,
) -> RunSummary:
    """Start every node of a launch file in order, watch them, stop them in reverse order.

    ``processes`` (default: the bus crosses processes, not ``mem://``, in a numbered domain)
    runs each container in a process (:mod:`hil_bridge.launch.process`; a node alone by default,
    :func:`~hil_bridge.launch.spec.compose_lockstep`); else every node is a thread of this one.
    ``only``/``skip`` name the nodes to run or leave out; ``realtime`` False runs them at normal
    scheduling, whatever their ``realtime`` keys; ``log_dir`` receives one log file per process.
    ``monitor`` False runs no bus monitor (``echoloop run``: a node alone must not decode every
    message of the bus in its own process). ``speed`` (sim s per wall s, None: max; ``"file"``:
    as the file says) paces the run (:func:`~hil_bridge.launch.spec.with_speed`); ``compose``
    False keeps a lockstep server and its firmware nodes in processes of their own.

    The run ends ``duration`` seconds after every node started (argument, else the file's;
    ``None`` = until a signal), on SIGINT/SIGTERM (handlers installed only when called from the
    main thread and ``handle_signals``), when ``stop_event`` is set, or as soon as a launchable
    says it failed (``stopped_by`` ``"failure"``; the module docstring); with
    ``until_finished``, also once every launchable with an end is finished (``stopped_by``
    ``"finished"``: ``echoloop replay`` ends when its trajectory does). ``record`` writes every
    topic to MCAP with :class:`hil_bridge.recording.recorder.Recorder`. ``live`` starts the
    Foxglove view (:mod:`hil_bridge.tools.live`). ``bus`` replaces the file's bus URL.
    ``domain`` (default ``ECHOLOOP_DOMAIN``, else 0) gives every default the file leaves out:
    the bus, pty links, virtual CAN channels, the live-view port. ``on_started(spec)`` is called
    once every node runs, with ``spec.bus`` the bus in use. A node whose constructor or
    ``start()`` raises fails the run (every node already constructed is stopped, in reverse
    order); one that refuses its params raises ConfigError. ``overwrite`` lets ``record`` and
    the nodes' own outputs (nodes with an ``overwrite`` parameter) replace existing files.
    ``after_run`` (step name -> ``step(summary)``) runs once everything stopped (the recording
    is complete), in order, whatever the run's outcome; a step that raises is a failure of that
    step (:data:`EXIT_AFTER_RUN`).

    ``expect`` (``"NODE.COUNTER OP VALUE"`` strings, checked for unknown nodes before anything
    starts), ``allow_disconnected``, the launchables that fail and the ``after_run`` steps that
    fail decide the summary's ``failures`` and ``exit_status`` (:func:`judge`).
    """
    spec = path if isinstance(path, LaunchSpec) else load(
        path, params_overrides=params_overrides, allow_modules=allow_modules)
    spec = select_nodes(spec, only=only, skip=skip)  # all of them unless told
    spec = spec if realtime else spec.without_realtime()
    dom = resolve(domain)
    bus_url = bus if bus is not None else spec.bus or dom.bus_url
    spec = dataclasses.replace(spec, bus=bus_url)
    in_processes = processes_for(bus_url, dom) if processes is None else processes
    spec = spec if speed == "file" else with_speed(spec, speed)
    spec = compose_lockstep(spec) if in_processes and compose else spec
    if in_processes and processes_for(bus_url, dom) is False:
        raise ConfigError(f"nodes as processes need a bus that crosses processes (tcp:// or "
                          f"ipc://) in a numbered domain; {bus_url} in {dom} lives in one "
                          "process: run the nodes as threads")
    expectations = parse_expectations(
        [e for e in expect if isinstance(e, str)], nodes=[n.name for n in spec.nodes]
    ) + [e for e in expect if isinstance(e, Expectation)]
    if duration is not None:
        check_duration(duration)
    run_for = duration if duration is not None else spec.duration
    record_path = str(record) if record is not None else spec.record
    want_live = spec.live if live is None else live

    flag = _StopFlag()
    previous: dict[signal.Signals, Any] = {}
    if handle_signals and threading.current_thread() is threading.main_thread():

        def _on_signal(signum: int, _frame: FrameType | None) -> None:
            flag.set(signal.Signals(signum).name)

        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            previous[sig] = signal.signal(sig, _on_signal)

    made: list[tuple[str, Any]] = []
    extras: list[Any] = []
    own = RunThreads()
    watch = _Watch()
    t0 = time.monotonic()
    held = contextlib.ExitStack()
    held.enter_context(dom.claim())
    rt = spec.realtime if in_processes else 0  # the proxy and monitor of real-time nodes
    if rt and not can_realtime(rt):
        _warn_no_realtime(spec)
    proxy = proxy_for(bus_url, realtime=rt) if launch_proxy(spec) else None
    try:
        with use(dom):
            if proxy is not None:
                proxy.start()
            if monitor:
                bus_monitor = BusMonitor("launch_monitor", bus=bus_url, realtime=min(rt, 1))
                bus_monitor.start()
                extras.append(bus_monitor)
            if record_path is not None:
                from hil_bridge.recording.recorder import Recorder

                recorder = Recorder(record_path, bus=bus_url, overwrite=overwrite)
                recorder.start()
                extras.append(recorder)
            try:
                if in_processes:
                    started = _spawn(spec, bus_url, watch, made, overwrite=overwrite, domain=dom,
                                     log_dir=None if log_dir is None else Path(log_dir),
                                     sync=proxy is not None)
                else:
                    started = _instantiate(spec, bus_url, watch, made, overwrite=overwrite)
            except ConfigError as exc:  # a node refused its params: say which launch file
                if isinstance(path, str | Path) and str(path) not in str(exc):
                    raise ConfigError(f"{path}: {exc}") from None
                raise
            started = started and _start(made, watch, None if proxy is None else bus_url)
            if started and want_live:
                from hil_bridge.tools.live import LiveView

                view = LiveView("live", bus=bus_url)
                view.start()
                extras.append(view)
            if started and rt:  # the monitor's process: none of the launch's threads at normal
                own.raise_to(min(rt, 1))  # priority takes the lock while the run lasts
        watch.items = [*made, *((extra.name, extra) for extra in extras)]
        if not started:
            flag.set("failure")
        else:
            if on_started is not None:
                on_started(spec)
            _wait(flag, watch, run_for, stop_event, until_finished)
    finally:
        # a recoverable fault still pending now was never recovered: asked before anything
        # stops, so a node stopping first cannot make another's link drop look like a failure
        for name, obj in [*made, *((extra.name, extra) for extra in extras)]:
            watch.ask(name, obj, final=True)
        node_stats: dict[str, dict[str, Any]] = {}
        for name, obj in reversed(made):
            node_stats[name] = watch.stop_and_collect(name, obj)
        monitor_stats: dict[str, Any] = {}
        extra_stats: dict[str, dict[str, Any]] = {}
        for extra in reversed(extras):
            stats = watch.stop_and_collect(extra.name, extra)
            if isinstance(extra, BusMonitor):
                monitor_stats = stats
            else:
                extra_stats[extra.name] = stats
        if proxy is not None:
            proxy.stop()
        own.restore()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        held.close()
    nodes = {name: node_stats[name] for name, _ in made}
    summary = RunSummary(
        wall_s=time.monotonic() - t0, stopped_by=flag.reason, nodes=nodes, monitor=monitor_stats,
        record=record_path, extras=extra_stats, domain=str(dom), bus=bus_url,
        links=collect_links(nodes), mode="processes" if in_processes else "threads",
        containers={n.container: [m.name for m in spec.nodes if m.container == n.container]
                    for n in spec.nodes if n.container and in_processes})
    steps_failed: list[tuple[str, str]] = []
    for step, action in (after_run or {}).items():
        try:
            action(summary)
        except Exception as exc:  # reported and judged; never instead of the run's status
            log.exception("%s failed after the run", step)
            steps_failed.append((step, _describe(exc)))
    summary.failures = judge(
        summary, expectations=expectations, allow_disconnected=allow_disconnected,
        failed=watch.failed, after_run=steps_failed,
    )
    return summary
