"""Simulated CANopen devices of an ehactl rig: a CiA 406 position transducer and a CiA 408 valve
with on-board electronics, served from our EDS files (configs/eds) with python-can and the
``canopen`` package and backed by one shared ``ehactl.Plant``.

Run ``python -m ehactl.devices --bus socketcand://127.0.0.1:PORT/can0 --config CONFIG``; see
README.md next to this file and the ICD for the objects, timing and fault injection.
"""

from .node import SimNode
from .rig import CanopenSettings, DeviceError, Fault, SimRig, load_canopen_settings, parse_fault
from .transducer import Transducer
from .valve import ValveObe, ValveState

__all__ = ["SimNode", "SimRig", "Transducer", "ValveObe", "ValveState", "CanopenSettings",
           "DeviceError", "Fault", "load_canopen_settings", "parse_fault"]
