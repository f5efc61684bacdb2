"""The launch file: plain data, validated once at load into a :class:`LaunchSpec`.

A launch file is plain data (no substitutions, conditions or event handlers)::

    bus: mem://demo              # optional; default the domain's (hil_bridge.bus.domain)
    allow_modules: [my_lab.nodes]   # optional; entries outside the project packages
    duration: 20                 # optional default run time in seconds (CLI --duration wins)
    record: out/run.mcap         # optional MCAP recording of every topic (CLI --record wins)
    compose_lockstep: true       # optional; false keeps a lockstep server and its partners apart
    nodes:
      - name: server
        entry: hil_bridge.server:SimServer
        params: {scene: {...}}
      - name: sonar_head
        entry: drivers.serial.adapter:SonarHeadAdapter
        params: {port: /dev/ttyUSB0}
        realtime: 20             # optional SCHED_FIFO priority of its threads (docs/launch.md)

It is validated once, at load, into :class:`LaunchSpec` (unknown keys raise a
:class:`~sim_core.config.ConfigError` naming the key; every ``entry`` must import and name a
class with ``start``, ``stop`` and ``stats``). **A launch file runs code**: importing an entry
runs its module. Entries may come only from the project's packages (the installed
``hil_bridge``, ``drivers``, ``ros2_bridge``, ``sim_core``) and from modules listed under
``allow_modules:`` (or ``--allow-module``), and every entry is checked against that list
before the first import (:func:`check_entry_module`). :func:`node_params` gives the params a
node is constructed with; :func:`compose_lockstep` puts a lockstep server and its firmware
nodes in one container; :mod:`hil_bridge.launch.runner` runs a spec.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import inspect
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil_bridge.files.config import load_yaml, parse_override
from hil_bridge.priority import MAX_REALTIME
from sim_core.config import ConfigError, apply_overrides, from_dict

__all__ = [
    "PROJECT_PACKAGES",
    "LaunchSpec",
    "NodeSpec",
    "check_duration",
    "check_entry_module",
    "compose_lockstep",
    "launch_proxy",
    "load",
    "node_params",
    "parse_param_overrides",
    "parse_speed",
    "resolve_entry",
    "select_nodes",
    "with_speed",
]


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


@dataclass(frozen=True, slots=True)
class NodeSpec:
    """One node of a launch file: a unique ``name``, ``entry`` ``"pkg.module:Class"``, params,
    the ``container`` whose process it shares (default: a process of its own), and the
    ``realtime`` priority its threads run at (``SCHED_FIFO`` 1..98; 0: normal scheduling; a
    container runs at the highest of its nodes')."""

    name: str
    entry: str
    params: dict[str, Any] = field(default_factory=dict)
    container: str = ""
    realtime: int = 0

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "a").isalnum():
            raise ValueError(f"name: expected [A-Za-z0-9_]+, got {self.name!r}")
        if self.container and not self.container.replace("_", "a").isalnum():
            raise ValueError(f"container: expected [A-Za-z0-9_]+, got {self.container!r}")
        if isinstance(self.realtime, bool) or not 0 <= self.realtime <= MAX_REALTIME:
            raise ValueError(f"realtime: expected a SCHED_FIFO priority 1..{MAX_REALTIME} "
                             f"(0: normal scheduling), got {self.realtime!r}")
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
    compose_lockstep: bool = True

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

    @property
    def realtime(self) -> int:
        """The highest ``realtime`` priority of the nodes (0: none asks for real time)."""
        return max(node.realtime for node in self.nodes)

    def without_realtime(self) -> LaunchSpec:
        """This launch with every node at normal scheduling (``echoloop launch --no-realtime``)."""
        return dataclasses.replace(
            self, nodes=tuple(dataclasses.replace(n, realtime=0) for n in self.nodes))

    def node(self, name: str) -> NodeSpec:
        for node in self.nodes:
            if node.name == name:
                return node
        raise KeyError(name)


#: the project's own packages: launch entries may always come from these
PROJECT_PACKAGES = ("hil_bridge", "drivers", "ros2_bridge", "sim_core")
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


def _takes(cls: type, param: str) -> bool:
    try:
        return param in inspect.signature(cls).parameters
    except (TypeError, ValueError):
        return False


def _embeds_proxy(cls: type, params: Mapping[str, Any]) -> bool:
    """Whether a node of ``cls`` with ``params`` would run the bus's proxy in its process: its
    class says it can (``EMBEDS_PROXY = True``, e.g. the simulation server) and its params do
    not set ``embed_proxy`` false."""
    return bool(getattr(cls, "EMBEDS_PROXY", False)) and bool(params.get("embed_proxy", True))


def node_params(node: NodeSpec, cls: type, *, overwrite: bool) -> dict[str, Any]:
    """``node``'s params as its constructor (``cls``) gets them: with ``overwrite``, nodes that
    take an ``overwrite`` parameter (those that write files) get ``overwrite=True`` unless their
    params set it; a node that would embed the bus's proxy gets ``embed_proxy=False`` (the
    launch runs the proxy, :func:`launch_proxy`)."""
    params = dict(node.params)
    if overwrite and "overwrite" not in params and _takes(cls, "overwrite"):
        params["overwrite"] = True
    if _embeds_proxy(cls, params):
        params["embed_proxy"] = False
    return params


def launch_proxy(spec: LaunchSpec) -> bool:
    """Whether the launch runs its bus's proxy: a node would embed one (``EMBEDS_PROXY``, and
    its params do not set ``embed_proxy`` false: the simulation server). The launch then starts
    the proxy before anything else and stops it last, so the bus outlives any node; such nodes
    get ``embed_proxy=False``."""
    return any(_embeds_proxy(resolve_entry(node.entry, where=f"nodes[{i}].entry",
                                           allow_modules=spec.allow_modules), node.params)
               for i, node in enumerate(spec.nodes))


#: the container :func:`compose_lockstep` makes
LOCKSTEP_CONTAINER = "lockstep"


def compose_lockstep(spec: LaunchSpec) -> LaunchSpec:
    """``spec`` with a lockstep server and its lockstep partners in one container, named
    :data:`LOCKSTEP_CONTAINER`, whose nodes deliver to each other in-process
    (:mod:`hil_bridge.bus.intra`): a node whose class's ``lockstep_host(params)`` is true (the
    simulation server with a ``lockstep`` clock) and every node whose class says
    ``LOCKSTEP_PARTNER = True`` (the firmware nodes: ArduPilot's JSON, PX4's HIL). Nodes that
    name a ``container:`` keep it; with ``compose_lockstep: false``, or without one host and one
    partner, ``spec`` is returned as it is."""
    if not spec.compose_lockstep:
        return spec
    free = [n for n in spec.nodes if not n.container]
    classes = {n.name: resolve_entry(n.entry, where=f"{n.name}.entry",
                                     allow_modules=spec.allow_modules) for n in free}
    hosts = [n.name for n in free
             if callable(getattr(classes[n.name], "lockstep_host", None))
             and classes[n.name].lockstep_host(n.params)]  # type: ignore[attr-defined]
    partners = [n.name for n in free
                if getattr(classes[n.name], "LOCKSTEP_PARTNER", False) is True]
    if len(hosts) != 1 or not partners:
        return spec
    names = {*hosts, *partners}
    return dataclasses.replace(spec, nodes=tuple(
        dataclasses.replace(n, container=LOCKSTEP_CONTAINER) if n.name in names else n
        for n in spec.nodes))


def parse_speed(text: str | float) -> float | None:
    """``--speed``: ``"max"`` (None: as fast as the loop goes) or sim seconds per wall second
    > 0; anything else raises ``ValueError`` naming the value and the expected form."""
    if isinstance(text, str) and text.strip().lower() == "max":
        return None
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = math.nan
    if not (value > 0 and math.isfinite(value)):
        raise ValueError(f"--speed: expected 'max' or sim seconds per wall second > 0, "
                         f"got {text!r}")
    return value


def with_speed(spec: LaunchSpec, speed: float | None) -> LaunchSpec:
    """``spec`` run at ``speed`` sim seconds per wall second (None: ``max``, as fast as it goes):
    every node whose class has ``speed_params(params, speed)`` gets the params it returns (the
    simulation server's clock, the PX4 node's pace before lockstep); the others keep theirs."""
    nodes = []
    for node in spec.nodes:
        cls = resolve_entry(node.entry, where=f"{node.name}.entry",
                            allow_modules=spec.allow_modules)
        hook = getattr(cls, "speed_params", None)
        nodes.append(node if hook is None else dataclasses.replace(
            node, params=dict(hook(node.params, speed))))
    return dataclasses.replace(spec, nodes=tuple(nodes))
