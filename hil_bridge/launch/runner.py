"""Launch = data + runner: run a YAML node graph as threads of one process.

A launch file is plain data (no substitutions, conditions or event handlers)::

    bus: mem://demo              # optional; default the domain's (hil_bridge.bus.domain)
    allow_modules: [my_lab.nodes]   # optional; entries outside hil_bridge/drivers/sim_core
    duration: 20                 # optional default run time in seconds (CLI --duration wins)
    record: out/run.mcap         # optional MCAP recording of every topic (CLI --record wins)
    nodes:
      - name: server
        entry: hil_bridge.server:SimServer
        params: {scene: {...}}
      - name: sonar_head
        entry: drivers.serial.adapter:SonarHeadAdapter
        params: {port: /dev/ttyUSB0}

It is validated once, at load, into :class:`LaunchSpec` (unknown keys raise a
:class:`~sim_core.config.ConfigError` naming the key; every ``entry`` must import and name a
class). **A launch file runs code**: importing an entry runs its module. Entries may come only
from the project's packages (the installed ``hil_bridge``, ``drivers``, ``sim_core``) and from
modules listed under ``allow_modules:`` (or ``--allow-module``), and every entry is checked
against that list before the first import (:func:`check_entry_module`).

Each entry implements the *launchable* contract: ``Cls(name, *, bus, **params)``, ``start()``
(non-blocking), ``stop()`` (idempotent, joins its threads) and ``stats() -> dict``, and
optionally ``failure() -> str | None`` (why it failed; the run then exits non-zero).

Why threads in one process, not processes: python-can's ``virtual`` interface only connects
buses of one process (the CAN adapter and the mock autopilot must share it), the mock sonar
head owns the master side of a pty whose slave path the serial adapter opens (both ends are
created and torn down together), and the ``mem://`` bus used by tests is in-process. The heavy
work (echo synthesis) is numpy/finufft code that releases the GIL.

Precedence of settings: CLI arguments (``--param``, ``--duration``, ``--record``, ``--bus``) >
the file > the domain's defaults. The run's domain (``run(domain=...)``, ``--domain``, else
``ECHOLOOP_DOMAIN``) is active while the nodes are constructed, so every default port, pty link
and virtual CAN channel a node picks is the domain's (:mod:`hil_bridge.bus.domain`).

**Exit status** (:attr:`RunSummary.exit_status`, computed in one place, :func:`judge`, from the
summary's ``failures``): 0 all well; otherwise the lowest code among the failures —
:data:`EXIT_FAILED` (1) a node or the recorder failed, :data:`EXIT_DISCONNECTED` (3) a hardware
link (a node's ``stats()["links"]`` entry) never connected, unless ``allow_disconnected``,
:data:`EXIT_EXPECT` (4) an expectation (:mod:`hil_bridge.launch.expect`) did not hold.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import importlib.util
import inspect
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any, Protocol, runtime_checkable

from hil_bridge.bus.domain import Domain, resolve, use
from hil_bridge.launch.expect import Expectation, parse_expectations
from hil_bridge.launch.monitor import BusMonitor
from hil_bridge.launch.process import ContainerProcess
from sim_core.config import ConfigError, apply_overrides, from_dict, load_yaml, parse_override

__all__ = [
    "EXIT_DISCONNECTED",
    "EXIT_EXPECT",
    "EXIT_FAILED",
    "EXIT_OK",
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
    "judge",
    "load",
    "parse_param_overrides",
    "resolve_entry",
    "run",
]

log = logging.getLogger(__name__)


#: exit status of a run that went well
EXIT_OK = 0
#: a node or the recorder failed
EXIT_FAILED = 1
#: a hardware link (serial port, CAN bus) never connected during the run
EXIT_DISCONNECTED = 3
#: an expectation (``--expect``) did not hold
EXIT_EXPECT = 4


def check_duration(seconds: float | str, *, where: str = "--duration") -> float:
    """``seconds`` if it is a finite number > 0, else ``ValueError`` naming ``where``."""
    prefix = f"{where}: " if where else ""
    try:
        value = float(seconds)
    except (TypeError, ValueError):
        value = math.nan
    if not (value > 0 and math.isfinite(value)):
        raise ValueError(f"{prefix}expected a finite number of seconds > 0, got {seconds!r}")
    return value


@runtime_checkable
class Launchable(Protocol):
    """What every launch entry implements (constructor ``Cls(name, *, bus, **params)``)."""

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def stats(self) -> dict[str, Any]: ...


@dataclass(frozen=True, slots=True)
class NodeSpec:
    """One node of a launch file: a unique ``name``, ``entry`` ``"pkg.module:Class"``, params,
    and the ``container`` whose process it shares (default: a process of its own)."""

    name: str
    entry: str
    params: dict[str, Any] = field(default_factory=dict)
    container: str = ""

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "a").isalnum():
            raise ValueError(f"name: expected [A-Za-z0-9_]+, got {self.name!r}")
        if self.container and not self.container.replace("_", "a").isalnum():
            raise ValueError(f"container: expected [A-Za-z0-9_]+, got {self.container!r}")
        module, sep, attr = self.entry.partition(":")
        if not sep or not module or not attr:
            raise ValueError(f"entry: expected 'package.module:Class', got {self.entry!r}")


@dataclass(frozen=True, slots=True)
class LaunchSpec:
    """A validated launch file (see the module docstring)."""

    nodes: tuple[NodeSpec, ...]
    bus: str | None = None
    duration: float | None = None
    record: str | None = None
    live: bool = False
    description: str = ""
    allow_modules: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.nodes:
            raise ValueError("nodes: expected at least one node")
        for name in self.allow_modules:
            if not all(part.isidentifier() for part in name.split(".")):
                raise ValueError(f"allow_modules: expected dotted module names, got {name!r}")
        seen: set[str] = set()
        for node in self.nodes:
            if node.name in seen:
                raise ValueError(f"nodes: duplicate node name {node.name!r}")
            seen.add(node.name)
        if self.duration is not None:
            check_duration(self.duration, where="duration")

    def node(self, name: str) -> NodeSpec:
        for node in self.nodes:
            if node.name == name:
                return node
        raise KeyError(name)


#: the project's own packages: launch entries may always come from these
PROJECT_PACKAGES = ("hil_bridge", "drivers", "sim_core")
_PROJECT_ROOT = Path(__file__).resolve().parents[2]


def _covered(module: str, allowed: Sequence[str]) -> bool:
    return any(module == a or module.startswith(a + ".") for a in allowed)


def check_entry_module(module_name: str, allow_modules: Sequence[str] = (), *,
                       where: str = "entry") -> None:
    """Refuse, before anything is imported, an entry module that is neither in the project's
    packages (:data:`PROJECT_PACKAGES`, and only the installed copy of them: a package of the
    same name planted in the working directory is refused) nor in ``allow_modules`` (a module
    or a package, with everything below it). ``ConfigError`` says which and how to allow it."""
    if _covered(module_name, allow_modules):
        return
    top = module_name.split(".")[0]
    if top in PROJECT_PACKAGES:
        loaded = sys.modules.get(top)
        origin = getattr(loaded, "__file__", None) if loaded is not None else None
        if origin is None:
            spec = importlib.util.find_spec(top)  # locates the package; runs none of its code
            origin = spec.origin if spec is not None else None
        if origin is not None and Path(origin).resolve().is_relative_to(_PROJECT_ROOT / top):
            return
        raise ConfigError(
            f"{where}: module {module_name!r} would be imported from {origin}, not from the "
            f"installed echoloop ({_PROJECT_ROOT}); refusing to run it"
        )
    raise ConfigError(
        f"{where}: module {module_name!r} is not allowed: launch entries come from the "
        f"project's packages {list(PROJECT_PACKAGES)} or from modules the launch file lists "
        f"under 'allow_modules:' (or --allow-module {module_name}); a launch file runs the "
        "code it names"
    )


def resolve_entry(entry: str, *, where: str = "entry", allow_modules: Sequence[str] = ()) -> type:
    """Import ``"pkg.module:Class"`` once :func:`check_entry_module` allows it; a refused,
    missing module or attribute raises ConfigError."""
    module_name, _, attr = entry.partition(":")
    check_entry_module(module_name, allow_modules, where=where)
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"{where}: cannot import module {module_name!r} ({exc})") from None
    try:
        obj = getattr(module, attr)
    except AttributeError:
        raise ConfigError(f"{where}: module {module_name!r} has no attribute {attr!r}") from None
    if not isinstance(obj, type):
        raise ConfigError(f"{where}: {entry!r} is not a class")
    for method in ("start", "stop", "stats"):
        if not callable(getattr(obj, method, None)):
            raise ConfigError(f"{where}: {entry!r} has no {method}() (not a launchable node)")
    return obj


def parse_param_overrides(items: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``["server.scene.seed=3", "sonar_head.port=/dev/ttyUSB0"]`` -> per-node dotted overrides."""
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        key, value = parse_override(item)
        node, sep, rest = key.partition(".")
        if not sep or not rest:
            raise ConfigError(f"--param {item!r}: expected NODE.KEY=VALUE")
        out.setdefault(node, {})[rest] = value
    return out


def load(
    path: str | Path | Mapping[str, Any],
    *,
    params_overrides: Mapping[str, Mapping[str, Any]] | None = None,
    allow_modules: Sequence[str] = (),
) -> LaunchSpec:
    """Load and validate a launch file (or an already parsed mapping).

    ``params_overrides`` maps node name -> {dotted param key: value}; an unknown node name raises.
    Every entry is checked against the allowed modules (the project's packages, the file's
    ``allow_modules``, and ``allow_modules`` here, from ``--allow-module``) before any import,
    then imported here, so a typo fails before any node starts.
    """
    data = path if isinstance(path, Mapping) else load_yaml(path)
    where = "launch" if isinstance(path, Mapping) else str(path)
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping with a 'nodes' list, got {data!r}")
    if params_overrides:
        nodes = data.get("nodes")
        names = [n.get("name") for n in nodes if isinstance(n, Mapping)] if isinstance(
            nodes, list
        ) else []
        unknown = sorted(set(params_overrides) - set(names))
        if unknown:
            raise ConfigError(f"--param: unknown node(s) {unknown}; the file has {names}")
        new_nodes = []
        for n in nodes or []:
            over = params_overrides.get(str(n.get("name"))) if isinstance(n, Mapping) else None
            if over:
                n = {**n, "params": apply_overrides(n.get("params") or {}, over)}
            new_nodes.append(n)
        data = {**data, "nodes": new_nodes}
    try:
        spec = from_dict(LaunchSpec, data)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if allow_modules:
        spec = dataclasses.replace(
            spec, allow_modules=(*spec.allow_modules, *allow_modules))
    for i, node in enumerate(spec.nodes):  # every entry checked before the first import
        check_entry_module(node.entry.partition(":")[0], spec.allow_modules,
                           where=f"{where}: nodes[{i}].entry")
    for i, node in enumerate(spec.nodes):
        resolve_entry(node.entry, where=f"{where}: nodes[{i}].entry",
                      allow_modules=spec.allow_modules)
    return spec


@dataclass(frozen=True, slots=True)
class Failure:
    """One reason a run did not go well: its exit ``code``, where it came from (a node name,
    ``node.link``, ``expect``) and one line saying what happened."""

    code: int
    source: str
    message: str


@dataclass(slots=True)
class RunSummary:
    """What a run produced: wall time, why it stopped, per-node stats, bus-level monitor counts,
    the stats of the recorder / live view when they ran (``extras``, by name), the run's domain
    and bus, every hardware link's state (``links``, ``"node.label"`` -> the node's report),
    the ``failures`` that decide :attr:`exit_status`, and whether the nodes ran as
    ``"processes"`` or ``"threads"`` (``mode``)."""

    wall_s: float
    stopped_by: str
    nodes: dict[str, dict[str, Any]]
    monitor: dict[str, Any] = field(default_factory=dict)
    record: str | None = None
    extras: dict[str, dict[str, Any]] = field(default_factory=dict)
    domain: str = ""
    bus: str = ""
    links: dict[str, dict[str, Any]] = field(default_factory=dict)
    failures: list[Failure] = field(default_factory=list)
    mode: str = "threads"

    @property
    def exit_status(self) -> int:
        """0 when nothing failed, else the lowest code among :attr:`failures`."""
        return min((f.code for f in self.failures), default=EXIT_OK)

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["exit_status"] = self.exit_status
        return out


def collect_links(nodes: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Every node's ``stats()["links"]`` under ``"node.label"``.

    A link report is ``{"kind": "serial" | "can", "target": str, "connected": bool (ever during
    the run), "state": str (at the end of the run), "error": str}``.
    """
    out: dict[str, dict[str, Any]] = {}
    for name, stats in nodes.items():
        links = stats.get("links")
        if isinstance(links, Mapping):
            for label, report in links.items():
                out[f"{name}.{label}"] = dict(report)
    return out


def judge(
    summary: RunSummary, *, expectations: Sequence[Expectation] = (),
    allow_disconnected: bool = False, failed: Sequence[tuple[str, str]] = (),
) -> list[Failure]:
    """The one place that decides what failed in a run (and so its exit status).

    ``failed`` holds ``(source, reason)`` for launchables (nodes, the recorder) that reported
    failing (their optional ``failure()``) or whose ``stop()``/``stats()`` raised."""
    failures = [Failure(EXIT_FAILED, source, f"{source} failed: {reason}")
                for source, reason in failed]
    if not allow_disconnected:
        for key, link in summary.links.items():
            if not link.get("connected"):
                why = link.get("error") or "no error reported"
                failures.append(Failure(
                    EXIT_DISCONNECTED, key,
                    f"{key}: {link.get('kind', 'hardware')} link {link.get('target', '?')} never "
                    f"connected during the run ({why}); --allow-disconnected accepts that",
                ))
    for expectation in expectations:
        problem = expectation.check(summary.nodes)
        if problem is not None:
            failures.append(Failure(EXIT_EXPECT, "expect", problem))
    return failures


def failure_of(obj: Any, *, final: bool = False) -> str | None:
    """A launchable's own account of failing: its optional ``failure() -> str | None``
    (``failure(final=True)`` at the end of the run, when it takes ``final``)."""
    report = getattr(obj, "failure", None)
    if not callable(report):
        return None
    if final and "final" in inspect.signature(report).parameters:
        answer: str | None = report(final=True)
        return answer
    answer = report()
    return answer


#: how often (s) a running launch asks its nodes whether they failed
FAILURE_POLL_S = 0.25


def _first_failing(made: Sequence[tuple[str, Any]]) -> str | None:
    """The name of the first node that reports a failure while the run goes, or None."""
    for name, obj in made:
        try:
            if failure_of(obj):
                return name
        except Exception:  # a node that cannot even answer has failed
            return name
    return None


def _stop_and_collect(name: str, obj: Any, failed: list[tuple[str, str]]) -> dict[str, Any]:
    """Stop one launchable and take its stats; whatever goes wrong is noted in ``failed``."""
    stats: dict[str, Any] = {}
    for step in ("stop", "stats", "failure"):
        try:
            if step == "stop":
                obj.stop()
            elif step == "stats":
                stats = obj.stats()
            else:
                reason = failure_of(obj, final=True)
                if reason:
                    failed.append((name, reason))
        except Exception as exc:  # one broken node must not hide the others' results
            log.exception("%s: %s() raised", name, step)
            failed.append((name, f"{step}() raised {type(exc).__name__}: {exc}"))
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


def _takes_overwrite(cls: type) -> bool:
    try:
        return "overwrite" in inspect.signature(cls).parameters
    except (TypeError, ValueError):
        return False


def _node_params(i: int, node: NodeSpec, cls: type, *, overwrite: bool) -> dict[str, Any]:
    params = dict(node.params)
    if overwrite and "overwrite" not in params and _takes_overwrite(cls):
        params["overwrite"] = True
    return params


def _instantiate(
    spec: LaunchSpec, bus: str, made: list[tuple[str, Any]], *, overwrite: bool
) -> None:
    """Construct every node into ``made`` (so the caller can stop those built before a failure).

    With ``overwrite``, nodes whose constructor takes an ``overwrite`` parameter (those that
    write files: captures, CAN logs) get ``overwrite=True`` unless their params set it."""
    for i, node in enumerate(spec.nodes):
        cls = resolve_entry(node.entry, where=f"nodes[{i}].entry",
                            allow_modules=spec.allow_modules)
        params = _node_params(i, node, cls, overwrite=overwrite)
        try:
            obj = cls(node.name, bus=bus, **params)
        except TypeError as exc:
            raise ConfigError(f"nodes[{i}] ({node.name}).params: {exc}") from None
        made.append((node.name, obj))


def _spawn(
    spec: LaunchSpec, bus: str, made: list[tuple[str, Any]], *, overwrite: bool, domain: Domain,
    log_dir: Path | None,
) -> None:
    """Spawn every container's process at once (they import their nodes' modules meanwhile),
    then have each construct its nodes in the order of its first node; ``made`` gets a
    :class:`~hil_bridge.launch.process.RemoteNode` per node, whose ``start()`` starts them."""
    containers: dict[str, list[dict[str, Any]]] = {}
    for i, node in enumerate(spec.nodes):
        cls = resolve_entry(node.entry, where=f"nodes[{i}].entry",
                            allow_modules=spec.allow_modules)
        containers.setdefault(node.container or node.name, []).append(
            {"name": node.name, "entry": node.entry,
             "params": _node_params(i, node, cls, overwrite=overwrite)})
    assert domain.number is not None
    procs = [ContainerProcess(key, nodes, bus=bus, domain=domain.number,
                              allow_modules=spec.allow_modules, log_dir=log_dir)
             for key, nodes in containers.items()]
    try:
        for proc in procs:  # every host imports its nodes' modules at once
            proc.spawn()
        for proc in procs:  # and constructs them in the file's order
            proc.construct()
            made.extend((n["name"], proc.node(n["name"])) for n in proc.nodes)
    finally:
        for proc in procs:
            if not any(name == proc.nodes[0]["name"] for name, _ in made):
                proc.kill()


def processes_for(bus: str, domain: Domain) -> bool:
    """Whether a launch on ``bus`` in ``domain`` can run its nodes as processes."""
    return not bus.startswith("mem://") and domain.number is not None


def select_nodes(spec: LaunchSpec, *, only: Sequence[str] = (),
                 skip: Sequence[str] = ()) -> LaunchSpec:
    """``spec`` with only the nodes named in ``only`` (all when empty), less those in ``skip``;
    a name the file does not have raises ConfigError."""
    names = [n.name for n in spec.nodes]
    unknown = sorted(set(only) - set(names)) + sorted(set(skip) - set(names))
    if unknown:
        raise ConfigError(f"--only/--skip: unknown node(s) {unknown}; the file has {names}")
    kept = tuple(n for n in spec.nodes
                 if (not only or n.name in only) and n.name not in skip)
    if not kept:
        raise ConfigError(f"--only/--skip leave no node to run (the file has {names})")
    return dataclasses.replace(spec, nodes=kept)


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
    processes: bool | None = None,
    only: Sequence[str] = (),
    skip: Sequence[str] = (),
    log_dir: str | Path | None = None,
    monitor: bool = True,
) -> RunSummary:
    """Start every node of a launch file in order, wait, stop them in reverse order.

    ``processes`` (default: whenever the bus crosses processes, i.e. it is not ``mem://``, and
    the domain is numbered) runs each container, by default each node, in a process of its own
    (:mod:`hil_bridge.launch.process`); otherwise every node is a thread of this process.
    ``only``/``skip`` name the nodes to run or leave out; ``log_dir`` receives one log file per
    process. ``monitor`` False runs no bus monitor (``echoloop run``: a node alone must not
    decode every message of the bus in its own process).

    The run ends ``duration`` seconds after every node started (argument, else the file's;
    ``None`` = until a signal), on SIGINT/SIGTERM (handlers installed only when called from the
    main thread and ``handle_signals``), or when ``stop_event`` is set. ``record`` writes every
    topic to MCAP with :class:`hil_bridge.recording.bag.Recorder`. ``live`` starts the Foxglove view
    (:mod:`hil_bridge.tools.live`). ``bus`` replaces the file's bus URL. ``domain`` (default
    ``ECHOLOOP_DOMAIN``, else 0) gives every default the file leaves out: the bus, pty links,
    virtual CAN channels, the live-view port. ``on_started(spec)`` is called once every node
    runs, with ``spec.bus`` the bus in use. A node that fails to construct or start stops every
    node already constructed (reverse order) and re-raises. ``overwrite`` lets ``record`` and
    the nodes' own outputs (nodes with an ``overwrite`` parameter) replace existing files.

    ``expect`` (``"NODE.COUNTER OP VALUE"`` strings, checked for unknown nodes before anything
    starts), ``allow_disconnected`` and the launchables that fail (their optional ``failure()``
    returns a reason, or ``stop()``/``stats()`` raise) decide the summary's ``failures`` and
    ``exit_status`` (the module docstring).
    """
    spec = path if isinstance(path, LaunchSpec) else load(
        path, params_overrides=params_overrides, allow_modules=allow_modules)
    if only or skip:
        spec = select_nodes(spec, only=only, skip=skip)
    dom = resolve(domain)
    bus_url = bus if bus is not None else spec.bus or dom.bus_url
    spec = dataclasses.replace(spec, bus=bus_url)
    in_processes = processes_for(bus_url, dom) if processes is None else processes
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
    t0 = time.monotonic()
    held = contextlib.ExitStack()
    held.enter_context(dom.claim())
    try:
        with use(dom):
            if monitor:
                bus_monitor = BusMonitor("launch_monitor", bus=bus_url)
                bus_monitor.start()
                extras.append(bus_monitor)
            if record_path is not None:
                from hil_bridge.recording.recorder import Recorder

                recorder = Recorder(record_path, bus=bus_url, overwrite=overwrite)
                recorder.start()
                extras.append(recorder)
            try:
                if in_processes:
                    _spawn(spec, bus_url, made, overwrite=overwrite, domain=dom,
                           log_dir=None if log_dir is None else Path(log_dir))
                else:
                    _instantiate(spec, bus_url, made, overwrite=overwrite)
            except ConfigError as exc:  # a node refused its params: say which launch file
                if isinstance(path, str | Path) and str(path) not in str(exc):
                    raise ConfigError(f"{path}: {exc}") from None
                raise
            for _, obj in made:
                obj.start()
            if want_live:
                from hil_bridge.tools.live import LiveView

                view = LiveView("live", bus=bus_url)
                view.start()
                extras.append(view)
        if on_started is not None:
            on_started(spec)
        deadline = None if run_for is None else time.monotonic() + run_for
        next_check = time.monotonic() + FAILURE_POLL_S
        while not flag.event.is_set():
            if stop_event is not None and stop_event.is_set():
                flag.set("stop_event")
                break
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                flag.set("duration")
                break
            if time.monotonic() >= next_check:
                next_check = time.monotonic() + FAILURE_POLL_S
                failing = _first_failing(made)
                if failing is not None:
                    flag.set(f"failure of {failing}")
                    break
            flag.event.wait(0.05 if remaining is None else min(0.05, remaining))
    finally:
        failed: list[tuple[str, str]] = []
        node_stats: dict[str, dict[str, Any]] = {}
        for name, obj in reversed(made):
            node_stats[name] = _stop_and_collect(name, obj, failed)
        monitor_stats: dict[str, Any] = {}
        extra_stats: dict[str, dict[str, Any]] = {}
        for extra in reversed(extras):
            stats = _stop_and_collect(extra.name, extra, failed)
            if isinstance(extra, BusMonitor):
                monitor_stats = stats
            else:
                extra_stats[extra.name] = stats
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        held.close()
    nodes = {name: node_stats[name] for name, _ in made}
    summary = RunSummary(
        wall_s=time.monotonic() - t0,
        stopped_by=flag.reason,
        nodes=nodes,
        monitor=monitor_stats,
        record=record_path,
        extras=extra_stats,
        domain=str(dom),
        bus=bus_url,
        links=collect_links(nodes),
        mode="processes" if in_processes else "threads",
    )
    summary.failures = judge(
        summary, expectations=expectations, allow_disconnected=allow_disconnected,
        failed=failed,
    )
    return summary
