"""ArduPilot SITL firmware owned by the SITL node: started with the run, stopped with it.

A user's ``arduplane`` (or any ArduPilot SITL binary) run as a child of the node that serves
its JSON port (:class:`drivers.ardupilot.sitl.ArduPilotSitl`, its ``binary`` parameter), so
that a launch starts, watches and stops the firmware with everything else:

- the command is ``BINARY --model JSON:HOST -I N [-w] --home LAT,LON,ALT,HEADING
  [--defaults FILE,...] [ARGS...]``: ``N`` the instance the node serves, so the firmware sends to
  the port the node bound; the parameter files and the binary are resolved to absolute paths
  when the node is built (a missing file fails the launch there, naming the key);
- it runs in a working directory of its own (SITL writes ``eeprom.bin``, ``logs/`` and
  ``terrain/`` where it runs): by default the run's domain directory ``sitlN``
  (:meth:`hil_bridge.bus.domain.Domain.path`), emptied when the firmware starts and removed
  when it stops; under the node's ``firmware_dir`` (``DIR/sitlN``) it is kept, with the
  firmware's output in ``firmware.log``;
- it dies with the process that started it (``PR_SET_PDEATHSIG`` SIGKILL), so a node host
  killed with -9 leaves no firmware behind; a host stopped normally stops it first;
- stopping sends SIGINT, as Ctrl-C would: a SITL whose JSON peer has gone quiet ignores SIGTERM
  ("No JSON sensor message received, resending servos", ArduPlane 4.7.0-dev), and leaves on
  SIGINT; SIGKILL after ``stop_timeout_s``;
- a firmware that exits while the run goes fails the node (its exit code or signal and its
  last output lines).
"""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import subprocess
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

__all__ = ["FirmwareProcess", "FirmwareSpec", "resolve_binary"]

_PR_SET_PDEATHSIG = 1
#: resolved once, in the parent: the child only calls it between fork and exec
_PRCTL: Any = getattr(ctypes.CDLL(None, use_errno=True), "prctl", None)
#: output lines kept for a failure's message
_TAIL = 5


@dataclass(frozen=True, slots=True)
class FirmwareSpec:
    """How one SITL instance's firmware is started when the node owns it (``binary`` set).

    ``home``: latitude deg, longitude deg, altitude m, heading deg (SITL's ``--home``: the
    scene's geodetic origin, where the vehicle starts); ``defaults``: parameter files, loaded
    in order (``--defaults``); ``wipe``: ``-w``, SITL's stored parameters wiped so the files
    apply; ``args``: further arguments, passed as they are; ``stop_timeout_s``: how long it has
    to leave after SIGINT."""

    home: tuple[float, float, float, float] | None = None
    defaults: tuple[str, ...] = ()
    wipe: bool = True
    args: tuple[str, ...] = ()
    stop_timeout_s: float = 5.0

    def __post_init__(self) -> None:
        if self.home is not None and len(self.home) != 4:
            raise ValueError(f"home: expected [lat, lon, alt, heading], got {list(self.home)}")
        if not 0 < self.stop_timeout_s <= 60:
            raise ValueError(f"stop_timeout_s: expected 0 < s <= 60, got {self.stop_timeout_s}")


def resolve_binary(binary: str, where: str) -> str:
    """The absolute path of an executable ``binary`` (a path, or a name on ``PATH``)."""
    found = shutil.which(binary) if os.sep not in binary else (
        binary if os.access(binary, os.X_OK) and os.path.isfile(binary) else None)
    if found is None:
        raise ValueError(f"{where}: {binary!r} is no executable file (an ArduPilot SITL binary "
                         "such as build/sitl/bin/arduplane)")
    return os.path.abspath(found)


def _dies_with(parent: int) -> Callable[[], None]:
    """What the child runs between fork and exec: SIGKILL when its parent dies, and no exec at
    all if the parent is already gone."""

    def child() -> None:
        if _PRCTL is not None:
            _PRCTL(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        if os.getppid() != parent:
            os._exit(1)

    return child


class FirmwareProcess:
    """One SITL instance's firmware process (module docstring)."""

    def __init__(self, binary: str, spec: FirmwareSpec, *, instance: int, host: str,
                 workdir: Path, keep: bool, where: str) -> None:
        if spec.home is None:
            raise ValueError(f"{where}.firmware.home: expected [lat, lon, alt, heading] (the "
                             "scene's origin) for the firmware the node starts")
        self.where = where
        self.keep = keep
        self.workdir = workdir.resolve()
        defaults = []
        for f in spec.defaults:
            p = Path(f).resolve()
            if not p.is_file():
                raise ValueError(f"{where}.firmware.defaults: {f!r}: no such file")
            defaults.append(str(p))
        self.command = [binary, "--model", f"JSON:{host}", "-I", str(instance),
                        *(["-w"] if spec.wipe else []),
                        "--home", ",".join(f"{v:g}" for v in spec.home),
                        *(["--defaults", ",".join(defaults)] if defaults else []), *spec.args]
        self.stop_timeout_s = spec.stop_timeout_s
        self._proc: subprocess.Popen[bytes] | None = None
        self._out: IO[bytes] | None = None
        self._tail: deque[str] = deque(maxlen=_TAIL)
        self._pump: threading.Thread | None = None
        self._stopping = False

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def start(self) -> None:
        """Start it in its working directory (call from a thread that lasts the run: the
        kernel's parent-death signal follows the thread that forked)."""
        if not self.keep:
            shutil.rmtree(self.workdir, ignore_errors=True)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self._out = open(self.workdir / "firmware.log", "ab")
        self._proc = subprocess.Popen(
            self.command, cwd=self.workdir, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, preexec_fn=_dies_with(os.getpid()))
        self._pump = threading.Thread(target=self._copy_output, name=f"{self.where}-output",
                                      daemon=True)
        self._pump.start()

    def _copy_output(self) -> None:
        assert self._proc is not None and self._proc.stdout is not None and self._out
        for line in self._proc.stdout:
            self._out.write(line)
            self._out.flush()
            text = line.decode("utf-8", "replace").strip()
            if text:
                self._tail.append(text)

    def failure(self) -> str | None:
        """Why the firmware is gone while the run goes (it exited by itself), or None."""
        if self._proc is None or self._stopping:
            return None
        code = self._proc.poll()
        if code is None:
            return None
        how = (f"killed by {signal.Signals(-code).name}" if code < 0
               else f"exited with code {code}")
        last = f"; its last output: {' | '.join(self._tail)}" if self._tail else ""
        return f"{self.where}: firmware {Path(self.command[0]).name} (pid {self._proc.pid}) {how}" \
               f"{last}"

    def stop(self) -> int | None:
        """Stop it (SIGINT, SIGKILL after ``stop_timeout_s``), remove a working directory of
        the domain's; its exit code (negative: the signal), None if it never started."""
        if self._proc is None:
            return None
        self._stopping = True
        if self._proc.poll() is None:
            self._proc.send_signal(signal.SIGINT)
            try:
                self._proc.wait(self.stop_timeout_s)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        if self._pump is not None:
            self._pump.join()
        if self._out is not None:
            self._out.close()
            self._out = None
        if not self.keep:
            shutil.rmtree(self.workdir, ignore_errors=True)
        return self._proc.returncode
