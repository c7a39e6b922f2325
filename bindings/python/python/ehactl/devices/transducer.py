"""Simulated CiA 406 magnetostrictive linear position transducer (like the Novostrictive TMI of
seed 003): position of magnet 1 (0x6020:01, INTEGER32 in steps of 0x6005:01 nm) and its speed
(0x6030:01, INTEGER16 in steps of 0x6005:02 µm/s; 0x6004 = position value, same as 0x6020:01), sent synchronously on SYNC (TPDO type 1..240)
or cyclically every 0x6200 ms (TPDO type 254/255)."""

from __future__ import annotations

import math

from .node import PdoConfig, SimNode

I32_MIN, I32_MAX = -(2**31), 2**31 - 1
I16_MIN, I16_MAX = -(2**15), 2**15 - 1


def _clamp(v: int, lo: int, hi: int) -> int:
    return lo if v < lo else hi if v > hi else v


class Transducer(SimNode):
    """Position transducer node; the rig feeds it the plant's measured position each SYNC."""

    kind = "transducer"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.position_m = 0.0   # last sampled piston position (m)
        self.speed_m_s = 0.0    # finite difference of successive samples (m/s)
        self._prev: tuple[float, float] | None = None  # (t s, position m)

    def sample(self, t: float, position_m: float) -> None:
        """New position sample at plant time t (s); speed = Δx/Δt as the sensor electronics do."""
        if not math.isfinite(position_m):
            return
        if self._prev is not None and t > self._prev[0]:
            self.speed_m_s = (position_m - self._prev[1]) / (t - self._prev[0])
        self._prev = (t, position_m)
        self.position_m = position_m

    def position_counts(self) -> int:
        step_m = self.value(0x6005, 1) * 1e-9
        return _clamp(round(self.position_m / step_m), I32_MIN, I32_MAX)

    def speed_counts(self) -> int:
        step_m_s = self.value(0x6005, 2) * 1e-6
        return _clamp(round(self.speed_m_s / step_m_s), I16_MIN, I16_MAX)

    def live_value(self, index: int, sub: int):
        if (index == 0x6020 and sub == 1) or index == 0x6004:
            return self.position_counts()
        if index == 0x6030 and sub == 1:
            return self.speed_counts()
        return super().live_value(index, sub)

    def on_app_write(self, index: int, sub: int, value) -> None:
        pass  # 0x6000/0x6005/0x6200 are plain parameters (limits checked from the EDS)

    def async_period_s(self, cfg: PdoConfig) -> float:
        """CiA 406: the cyclic timer 0x6200 (ms) drives the event-driven TPDO; else 0x180x:05."""
        cyclic = self.value(0x6200)
        return cyclic / 1000.0 if cyclic > 0 else super().async_period_s(cfg)
