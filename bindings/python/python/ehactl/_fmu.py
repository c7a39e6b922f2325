"""``ehactl.export_fmu``: a config as an FMI 2.0 co-simulation FMU, as ``ehactl export-fmu``
writes it (docs/fmu.md). The FMU's binary is the generic library ``libehactl_fmu.so``
(crate ``ehactl-fmu``), found as the CLI finds it."""

from __future__ import annotations

import os
import pathlib
import shutil
from typing import Optional, Union

from ._ehactl import Config, export_fmu_file

_LIB = "libehactl_fmu.so"
_Path = Union[str, "os.PathLike[str]"]


def _library(binary: Optional[_Path]) -> pathlib.Path:
    """The FMU library: ``binary``, else ``$EHACTL_FMU_LIB``, else beside the ``ehactl``
    executable on PATH or in ``../lib/ehactl/`` from it."""
    if binary is not None:
        tried = [pathlib.Path(binary)]
    elif os.environ.get("EHACTL_FMU_LIB"):
        tried = [pathlib.Path(os.environ["EHACTL_FMU_LIB"])]
    else:
        exe = shutil.which("ehactl")
        tried = []
        if exe:
            d = pathlib.Path(exe).resolve().parent
            tried = [d / _LIB, d.parent / "lib" / "ehactl" / _LIB]
    for p in tried:
        if p.is_file():
            return p
    where = ", ".join(str(p) for p in tried) or "no `ehactl` on PATH"
    raise FileNotFoundError(
        f"the FMU library {_LIB} was not found (looked at: {where}); build it with "
        "`cargo build --release -p ehactl-fmu` (scripts/install_and_run.sh installs it) or pass binary=PATH")


def export_fmu(config: Union[Config, _Path], out: _Path, closed_loop: bool = False,
               binary: Optional[_Path] = None, aarch64_binary: Optional[_Path] = None) -> pathlib.Path:
    """Write ``config`` (a :class:`Config` or a TOML path) as an FMI 2.0 co-simulation FMU
    to ``out`` (``.fmu``): the plant (input the valve command u, V) or with
    ``closed_loop=True`` ehactl's control law and supervisor around it (input the setpoint,
    N or m). Returns ``out`` as a path. Raises FileNotFoundError when the library is not
    found, ValueError for a config the loader refuses or an ``out`` not ending in ``.fmu``."""
    out = pathlib.Path(out)
    if out.suffix != ".fmu":
        raise ValueError(f"out={str(out)!r}: expected a file name ending in .fmu")
    text = config.to_toml() if isinstance(config, Config) else pathlib.Path(config).read_text()
    lib = _library(binary)
    platform = "aarch64-linux" if os.uname().machine in ("aarch64", "arm64") else "linux64"
    binaries = [(platform, str(lib))]
    if aarch64_binary is not None and platform != "aarch64-linux":
        binaries.append(("aarch64-linux", str(aarch64_binary)))
    export_fmu_file(text, str(out), closed_loop, binaries)
    return out
