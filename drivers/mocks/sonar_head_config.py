"""The mock sonar head's parameters: :class:`SonarHeadConfig` (launch ``params``, CLI flags,
``sonarsim://`` URL options), checked at construction."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.serial.protocol import Encoding

__all__ = ["BEAMWIDTH_RANGE_DEG", "SonarHeadConfig"]

#: seed 000, scenario II: beamwidth drawn from this interval (degrees) per ping
BEAMWIDTH_RANGE_DEG = (30.0, 65.0)


@dataclass(frozen=True, slots=True)
class SonarHeadConfig:
    """Mock sonar-head parameters (launch ``params`` / CLI flags).

    ``beamwidth``: full one-way -3 dB beamwidth in degrees, or ``"random"`` (uniform in
    [30, 65] per ping). ``encoding``: ``int16`` | ``iq16`` | ``float32`` (or 0/1/2), requested
    in every PING. ``threshold``: absolute first-return threshold in echo units (None: none);
    ``threshold_rel``: the level relative to the echo's peak below which no return counts
    (the rule: :mod:`sim_core.sensors.echo_range`).
    """

    rate_hz: float = 10.0
    beamwidth: float | str = "random"
    encoding: int | str = "int16"
    baudrate: int = 921600
    channels: int = 1
    az_deg: float = 0.0
    el_deg: float = 0.0
    f_center_hz: int = 70000
    decimation: int = 20
    threshold: float | None = None
    threshold_rel: float = 0.1
    sound_speed: float = 340.0
    seed: int = 0
    throttle: bool = True
    echo_timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if not 0 < self.rate_hz <= 1000:
            raise ValueError(f"rate_hz {self.rate_hz!r} must be in (0, 1000]")
        if isinstance(self.beamwidth, str):
            if self.beamwidth != "random":
                raise ValueError(f"beamwidth {self.beamwidth!r}: expected degrees or 'random'")
        elif not 0 < self.beamwidth < 180:
            raise ValueError(f"beamwidth {self.beamwidth!r} must be in (0, 180) degrees")
        Encoding.parse(self.encoding)
        if self.baudrate <= 0:
            raise ValueError(f"baudrate {self.baudrate!r} must be > 0")
        if not 1 <= self.channels <= 255:
            raise ValueError(f"channels {self.channels!r} must be in 1..255")
        if not 0 <= self.f_center_hz < 1 << 32 or not 0 <= self.decimation <= 0xFFFF:
            raise ValueError(f"f_center_hz {self.f_center_hz!r} / decimation "
                             f"{self.decimation!r} out of range (u32 / u16)")
        if self.threshold is not None and self.threshold <= 0:
            raise ValueError(f"threshold {self.threshold!r} must be > 0")
        if not 0 < self.threshold_rel <= 1:
            raise ValueError(f"threshold_rel {self.threshold_rel!r} must be in (0, 1]")
        if self.sound_speed <= 0 or self.echo_timeout_s <= 0:
            raise ValueError("sound_speed and echo_timeout_s must be > 0")
