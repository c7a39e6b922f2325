"""``python -m ehactl.devices --bus URL --config CONFIG [--fault KIND[@T] ...]``: run the
simulated transducer (CiA 406) and valve OBE (CiA 408) of a rig on a CAN bus until SIGINT/SIGTERM.

Exit codes: 0 stopped by signal, 1 bus connection lost, 2 bad argument / config / bus address.
"""

from __future__ import annotations

import argparse
import signal
import sys

from .rig import FAULT_KINDS, DeviceError, SimRig, parse_fault


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m ehactl.devices",
        description="Simulated CiA 406 position transducer + CiA 408 valve OBE on a CAN bus, "
                    "sharing one simulated ehactl plant (plant time advances per SYNC).")
    p.add_argument("--bus", required=True,
                   help="socketcand://HOST:PORT/CHANNEL or socketcan://CHANNEL")
    p.add_argument("--config", required=True, help="rig config TOML (plant + [canopen])")
    p.add_argument("--fault", action="append", default=[], metavar="KIND[@T]",
                   help=f"inject a fault; KIND one of {', '.join(FAULT_KINDS)}; T in simulated "
                        "seconds from the first SYNC (default 0)")
    p.add_argument("--events", metavar="PATH", help="append device events as JSON lines")
    p.add_argument("--eds-dir", metavar="DIR", help="directory with the two EDS files")
    p.add_argument("--boot-delay", type=float, default=0.0, metavar="S",
                   help="wait S seconds after connecting before the boot-up messages (s)")
    p.add_argument("--quiet", action="store_true", help="no event lines on stderr")
    args = p.parse_args(argv)
    try:
        faults = [parse_fault(s) for s in args.fault]
        if not (args.boot_delay >= 0):
            raise DeviceError(f"--boot-delay {args.boot_delay}: expected a number ≥ 0 (s)")
        rig = SimRig(args.bus, args.config, faults, args.events, args.eds_dir, args.quiet)
    except DeviceError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2

    def on_signal(signum, frame):
        rig.stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    s = rig.settings
    rig.start(args.boot_delay)
    print(f"ehactl.devices ready: transducer node {s.transducer_node_id} (CiA 406) and valve "
          f"node {s.valve_node_id} (CiA 408) on {args.bus}; SYNC {s.sync_rate_hz:g} Hz = "
          f"{rig.steps_per_sync} plant steps of {rig.control_dt * 1e3:g} ms", flush=True)
    code = rig.run_forever()
    rig.close()
    if rig.bus_lost:
        print(f"error: bus {args.bus}: {rig.bus_lost}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
