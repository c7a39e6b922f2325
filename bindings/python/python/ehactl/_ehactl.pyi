"""Type stubs of the compiled core ``ehactl._ehactl`` (pyo3). Units are SI."""

from __future__ import annotations

import os
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

__version__: str

_Path = Union[str, os.PathLike[str]]

class NumericalError(RuntimeError):
    """The simulated plant produced a non-finite state."""

class Config:
    """A validated rig configuration (TOML, SI units) with dict-like access by dotted path.

    ``cfg["control.pi.kp"]`` (V/V) reads a value, ``cfg["valve.rated_flow"] = 1e-2`` (m³/s)
    sets one and re-validates the whole config with the Rust loader: an invalid value raises
    ValueError naming the field and its expected unit, and leaves the config unchanged.
    """

    def __init__(self, toml_text: Optional[str] = None) -> None: ...
    @staticmethod
    def load(path: _Path) -> Config:
        """Load and validate a TOML rig config."""
    @staticmethod
    def from_toml(text: str) -> Config:
        """Parse and validate TOML text."""
    @staticmethod
    def from_dict(d: dict[str, Any]) -> Config:
        """Build and validate a config from a nested dict (the ``to_dict()`` form)."""
    def to_toml(self) -> str:
        """The whole config as TOML text (defaults filled in)."""
    def to_dict(self) -> dict[str, Any]:
        """The whole config as a nested dict (defaults filled in)."""
    def save(self, path: _Path) -> None:
        """Write the config as TOML; it loads back with ``Config.load`` and ``ehactl run``."""
    def __getitem__(self, path: str) -> Any: ...
    def __setitem__(self, path: str, value: Any) -> None: ...
    def __delitem__(self, path: str) -> None: ...
    def __contains__(self, path: str) -> bool: ...
    def update(self, values: dict[str, Any]) -> None:
        """Set several fields (dotted path → value), validated together (all or nothing)."""
    def with_values(self, values: dict[str, Any]) -> Config:
        """A copy with several fields changed."""
    def keys(self) -> list[str]:
        """Dotted paths of every leaf value."""
    @staticmethod
    def unit(path: str) -> Optional[str]:
        """Unit of a registered numeric parameter, None if not registered."""
    def copy(self) -> Config: ...
    def __copy__(self) -> Config: ...
    def __deepcopy__(self, memo: Any) -> Config: ...
    def __eq__(self, other: object) -> bool: ...
    @property
    def control_dt(self) -> float:
        """Control period 1 / run.control_rate_hz (s)."""
    @property
    def name(self) -> str:
        """``rig.name``."""
    @property
    def mode(self) -> str:
        """``"force"``, ``"position"`` or ``"open_loop"``."""
    @property
    def source(self) -> Optional[str]:
        """File the config was loaded from."""

class Plant:
    """The bare simulated actuator of a config, stepped one control period at a time."""

    def __init__(self, cfg: Config, control_dt: Optional[float] = None) -> None:
        """Configure and initialise at the config's control period (s) or ``control_dt``."""
    def reset(self) -> None:
        """Back to the initial state (t = 0, sensor noise re-seeded)."""
    def step(self, u_volts: float, n: int = 1) -> None:
        """Advance ``n`` control periods holding the valve command (V); GIL released."""
    def run_commands(self, u: npt.NDArray[np.float64]) -> dict[str, npt.NDArray[np.float64]]:
        """Apply one command (V) per period; sensor readings at the start of each period."""
    def measure(self) -> dict[str, float]:
        """Sensors now: t (s), force (N), position (m), p_a, p_b (Pa), spool (fraction)."""
    def state(self) -> dict[str, Any]:
        """Ground-truth state (SI units) incl. x (m), v (m/s), rod_force (N), stuck (bool)."""
    @property
    def t(self) -> float:
        """Simulated time (s)."""
    @property
    def control_dt(self) -> float:
        """Control period (s)."""
    @property
    def substeps(self) -> int:
        """Integration substeps per control period."""
    def hydraulic_stiffness(self, x: float) -> float:
        """Hydraulic stiffness at piston position x (m), N/m (003 eq. 15)."""
    def volumes(self, x: float) -> tuple[float, float]:
        """Chamber volumes (m³) at piston position x (m)."""

def param_table() -> list[tuple[str, str, str, str, str]]:
    """(path, unit, kind, range, description) of every registered numeric parameter."""

def run_one(
    cfg: Config,
    duration: Optional[float] = None,
    mcap: Optional[_Path] = None,
    fields: Optional[Sequence[str]] = None,
    progress: Optional[Callable[[int, int], Any]] = None,
    overwrite: bool = False,
) -> tuple[dict[str, np.ndarray], str]:
    """One closed-loop run (GIL released): (columns, summary JSON)."""

def run_batch(
    cfgs: Sequence[Config],
    duration: Optional[float] = None,
    mcap: Optional[Sequence[_Path]] = None,
    fields: Optional[Sequence[str]] = None,
    threads: Optional[int] = None,
    progress: Optional[Callable[[int, int], Any]] = None,
    overwrite: bool = False,
) -> list[tuple[dict[str, np.ndarray], str]]:
    """Closed-loop runs in parallel on a rayon pool (GIL released), in input order."""

def record_fields() -> list[tuple[str, str]]:
    """(name, unit) of every float result column."""

def read_mcap_raw(path: _Path) -> dict[str, Any]:
    """Raw MCAP contents: cdr columns, json texts, schemas, metadata, profile, library."""

def controller_response(cfg: Config, f_hz: Sequence[float]) -> tuple[list[float], list[float]]: ...
def sampled_margins(f_hz: Sequence[float], re: Sequence[float], im: Sequence[float]) -> dict[str, float]: ...
def linear_plant_response(
    cfg: Config, f_hz: Sequence[float], max_time: float = 5.0
) -> tuple[list[float], list[float], dict[str, Any]]:
    """Plant linearised at its operating point (ehactl-analysis): real and imaginary parts of
    P(e^{jωT}) at ``f_hz`` (N/V or m/V, command delay included) and the operating point."""

def analyze_json(cfg: Config) -> str:
    """``ehactl analyze --json`` of ``cfg`` as a JSON string (see ``ehactl.analyze``)."""

def sweep_json(
    cfg: Config,
    from_hz: float | None = None,
    to_hz: float | None = None,
    points: int = 30,
    amplitude: float | None = None,
    open_loop: bool = False,
    output: str | None = None,
    periods: float = 6.0,
    mcap: _Path | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> str:
    """``ehactl sweep --json`` of ``cfg`` as a JSON string (see ``ehactl.sweep``)."""

def campaign_json(
    cfg: Config,
    data: Sequence[_Path],
    validate: Sequence[_Path] = ...,
    out: _Path | None = None,
    force: bool = False,
) -> str:
    """``ehactl diagnose --data … --json`` of a campaign (see ``ehactl.diagnose``)."""

def predict_json(
    cfg: Config,
    data: Sequence[_Path],
    imposed_motion: bool = False,
    held_out: bool = False,
    out: _Path | None = None,
    force: bool = False,
) -> str:
    """``ehactl predict --json`` (see ``ehactl.predict``)."""

def diagnose_json(
    cfg: Config,
    data: _Path,
    validate: _Path | None = None,
    out: _Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    sensor_offsets: bool = False,
) -> tuple[str, list[str]]:
    """``ehactl diagnose --json`` of ``data`` against ``cfg`` and the replay notes (see ``ehactl.diagnose``)."""

def export_fmu_file(
    config_text: str,
    out: _Path,
    closed_loop: bool,
    binaries: Sequence[tuple[str, _Path]],
) -> None:
    """Write the FMU of ``config_text`` (see ``ehactl.export_fmu``)."""
