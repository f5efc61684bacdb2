"""Nodes in their own processes: the runner's side of a node host (:mod:`hil_bridge.launch.host`).

:class:`ContainerProcess` spawns one host process for a container (by default every node is
its own container; nodes that share a ``container:`` name share a process) and sends it the
nodes; :meth:`~ContainerProcess.construct` and :meth:`~ContainerProcess.start` have the host
construct, then start them, each waiting for the host's answer (``ready_timeout_s``; a host
that does not come up is named with its last log lines). :meth:`ContainerProcess.node` gives
the runner one :class:`RemoteNode` per node, which keeps the launchable contract (``start``,
``stop``, ``stats``, ``failure``) over the control channel.

A host that dies (an exception that ends it, ``os.abort``, SIGKILL, the kernel's OOM killer)
is a failure of each of its nodes that had not stopped: ``failure()`` names the exit code or
the signal and the host's last log lines. Every line a host writes to standard error is
forwarded to the runner's standard error prefixed with ``[node]`` (``[container]`` for a
container of several nodes) and, with ``log_dir``, appended to ``log_dir/<name>.log``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
from collections import deque
from collections.abc import Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import IO, Any

from hil_bridge.errors import HilError

__all__ = ["ContainerProcess", "NodeStartError", "RemoteNode"]

#: how many of a host's last log lines a failure quotes
TAIL_LINES = 12
#: how long a stopping node may take before its host is terminated
STOP_TIMEOUT_S = 30.0


class NodeStartError(HilError):
    """A node's process did not come up (it failed to start, died, or never reported ready)."""


def _signal_name(code: int) -> str:
    try:
        return signal.Signals(-code).name
    except ValueError:
        return f"signal {-code}"


class ContainerProcess:
    """One host process running the nodes ``nodes`` (``[{"name", "entry", "params"}]``, and
    ``"realtime"``: the host runs at the highest)."""

    def __init__(self, name: str, nodes: Sequence[dict[str, Any]], *, bus: str, domain: int,
                 allow_modules: Sequence[str] = (), log_dir: Path | None = None,
                 sync: bool = False, ready_timeout_s: float = 60.0,
                 stream: IO[str] | None = None) -> None:
        self.name = name
        self.nodes = [dict(n) for n in nodes]
        self.bus = bus
        self.domain = domain
        self.allow_modules = list(allow_modules)
        self.log_dir = log_dir
        self.sync = sync
        self.ready_timeout_s = ready_timeout_s
        self._stream = stream if stream is not None else sys.stderr
        self._proc: subprocess.Popen[bytes] | None = None
        self._conn: Connection | None = None
        self._lock = threading.Lock()
        self._tail: deque[str] = deque(maxlen=TAIL_LINES)
        self._pump: threading.Thread | None = None
        self._stopped: dict[str, tuple[dict[str, Any], str | None]] = {}
        self._started = False
        self._prefix = f"[{nodes[0]['name']}] " if len(nodes) == 1 else f"[{name}] "

    # ------------------------------------------------------------------ process

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def spawn(self) -> None:
        """Start the host process and hand it the nodes; it imports their modules meanwhile."""
        ours, theirs = socket.socketpair()
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "hil_bridge.launch.host", str(theirs.fileno()),
                 str(os.getpid())],
                pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env,
            )
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        self._pump = threading.Thread(target=self._pump_logs, name=f"log-{self.name}",
                                      daemon=True)
        self._pump.start()
        self._conn.send(("nodes", {"domain": str(self.domain), "bus": self.bus,
                                   "allow_modules": self.allow_modules, "sync": self.sync,
                                   "realtime": max(n.get("realtime", 0) for n in self.nodes),
                                   "nodes": self.nodes}))

    def construct(self) -> None:
        """Have the host construct its nodes (:meth:`spawn` first, if not yet) and wait for it,
        at most ``ready_timeout_s`` for the imports and as long again for the construction."""
        if self._proc is None:
            self.spawn()
        assert self._conn is not None
        self._expect("prepared")
        self._conn.send(("construct", None))
        self._expect("constructed")

    def start(self) -> None:
        """Have the host start its constructed nodes; wait until it reports them running."""
        if self._started:
            return
        self._started = True
        assert self._conn is not None
        self._conn.send(("start", None))
        try:
            self._expect("ready")
        except NodeStartError:  # reported by the raise; the host that ended is no more news
            self._stopped.update((n["name"], ({}, None)) for n in self.nodes)
            raise

    def _expect(self, what: str) -> None:
        assert self._conn is not None
        if not self._conn.poll(self.ready_timeout_s):
            self.kill()
            raise NodeStartError(f"{self._what()} did not report {what} within "
                                 f"{self.ready_timeout_s:g} s{self._tail_text()}")
        try:
            kind, detail = self._conn.recv()
        except (EOFError, OSError):
            self._reap()
            raise NodeStartError(f"{self._what()} died while starting "
                                 f"({self._exit_text()}){self._tail_text()}") from None
        if kind != what:
            self._reap()
            raise NodeStartError(f"{self._what()} failed to start: {detail}")

    def _what(self) -> str:
        names = ", ".join(n["name"] for n in self.nodes)
        return f"node {names}" if len(self.nodes) == 1 else f"container {self.name} ({names})"

    def _pump_logs(self) -> None:
        assert self._proc is not None and self._proc.stdout is not None
        sink = None
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            sink = open(self.log_dir / f"{self.name}.log", "a", encoding="utf-8")
        try:
            for raw in self._proc.stdout:
                line = raw.decode("utf-8", "replace").rstrip("\n")
                self._tail.append(line)
                with contextlib.suppress(ValueError, OSError):
                    self._stream.write(self._prefix + line + "\n")
                    self._stream.flush()
                if sink is not None:
                    sink.write(line + "\n")
                    sink.flush()
        finally:
            if sink is not None:
                sink.close()

    def _tail_text(self) -> str:
        if self._pump is not None:
            self._pump.join(timeout=1.0)
        lines = list(self._tail)
        return ("; last log lines:\n  " + "\n  ".join(lines)) if lines else ""

    def _exit_text(self) -> str:
        code = None if self._proc is None else self._proc.poll()
        if code is None:
            return "still running"
        return f"killed by {_signal_name(code)}" if code < 0 else f"exit code {code}"

    def alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def kill(self) -> None:
        """SIGKILL the host (when it does not stop or report) and reap it."""
        if self.alive():
            assert self._proc is not None
            with contextlib.suppress(ProcessLookupError):
                self._proc.kill()
        self._reap()

    def _reap(self) -> None:
        if self._proc is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._proc.wait(timeout=STOP_TIMEOUT_S)
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if self._pump is not None:
            self._pump.join(timeout=5.0)

    # ------------------------------------------------------------------ requests

    def _ask(self, kind: str, name: str, timeout: float) -> Any:
        with self._lock:
            conn = self._conn
            if conn is None or not self.alive():
                raise NodeStartError(f"{self._what()} is not running ({self._exit_text()})")
            try:  # the host may die between the question and its answer
                conn.send((kind, name))
                ready = conn.poll(timeout)
                answer, detail = conn.recv() if ready else (None, None)
            except (EOFError, OSError):
                self._reap()
                raise NodeStartError(f"{self._what()} died while asked for {kind}() "
                                     f"({self._exit_text()}){self._tail_text()}") from None
        if not ready:
            raise TimeoutError(f"{name}: no answer to {kind}() within {timeout:g} s")
        if answer == "error":
            raise HilError(f"{name}: {detail}")
        return detail

    def died(self) -> str | None:
        """Why the host is gone while nodes still ran in it, or None."""
        if self._proc is None or self.alive() or len(self._stopped) == len(self.nodes):
            return None
        return f"process died ({self._exit_text()}){self._tail_text()}"

    def stats_of(self, name: str) -> dict[str, Any]:
        if name in self._stopped:
            return self._stopped[name][0]
        stats: dict[str, Any] = self._ask("stats", name, timeout=10.0)
        return stats

    def failure_of(self, name: str, *, final: bool = False) -> str | None:
        if name in self._stopped:
            return self._stopped[name][1]
        dead = self.died()
        if dead is not None:
            return dead
        try:
            answer: str | None = self._ask("final_failure" if final else "failure", name,
                                           timeout=5.0)
        except TimeoutError:
            return None
        except NodeStartError as exc:  # it died while asked: why it died
            return self.died() or str(exc)
        return answer

    def finished_of(self, name: str) -> bool | None:
        if name in self._stopped or self.died() is not None:
            return None
        try:
            answer: bool | None = self._ask("finished", name, timeout=5.0)
        except (TimeoutError, NodeStartError):  # unanswered or gone: failure() says why
            return None
        return answer

    def stop_node(self, name: str) -> None:
        if name in self._stopped:
            return
        if not self.alive():
            self._stopped[name] = ({}, self.died() or f"process gone ({self._exit_text()})")
            self._finish_if_done()
            return
        try:
            stats, failure = self._ask("stop", name, timeout=STOP_TIMEOUT_S)
        except (TimeoutError, EOFError, OSError, NodeStartError) as exc:
            self._stopped[name] = ({}, f"did not stop cleanly ({exc}){self._tail_text()}")
            self.kill()
        else:
            self._stopped[name] = (stats, failure)
        self._finish_if_done()

    def _finish_if_done(self) -> None:
        if len(self._stopped) == len(self.nodes):
            if self._proc is not None:
                try:
                    self._proc.wait(timeout=STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    self._proc.terminate()
            self._reap()

    def node(self, name: str) -> RemoteNode:
        return RemoteNode(self, name)


class RemoteNode:
    """The launchable contract of node ``name`` running in ``container``'s process."""

    def __init__(self, container: ContainerProcess, name: str) -> None:
        self.container = container
        self.name = name

    def start(self) -> None:
        """Start the container's nodes (once, with the first of them)."""
        self.container.start()

    def stop(self) -> None:
        self.container.stop_node(self.name)

    def stats(self) -> dict[str, Any]:
        stats = dict(self.container.stats_of(self.name))
        stats.setdefault("pid", self.container.pid)
        return stats

    def failure(self, *, final: bool = False) -> str | None:
        return self.container.failure_of(self.name, final=final)

    def finished(self) -> bool | None:
        return self.container.finished_of(self.name)
