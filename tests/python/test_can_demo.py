"""The CAN demo exactly as docs/canopen.md shows it — one hub, one `python -m ehactl.devices`
with the shipped config, then `ehactl run configs/dindorf2022_boom.toml --hal canopen` — run
again and again with the config's own heartbeat times (ehactl's heartbeat every 20 ms, which
the devices consume with 100 ms; the devices' every 20 ms, consumed by ehactl with 60 ms).

Ten runs must end without a trip. The consumer times assume that every process on the path
(ehactl, the hub, the devices) is scheduled within the margin of its consumer (docs/canopen.md):
a run whose trip comes with a measured breach of that assumption — a 1 ms sleeper in this
process overslept by 40 ms or more, the hub stamped the devices' heartbeats more than 60 ms
apart or a SYNC's answer more than 50 ms late (the devices or the hub stalled), or ehactl's
own summary shows a loop that started no cycle for the devices' margin (`period_max_us` ≥
80 ms), or, for a trip of ehactl's own consumer, ehactl's loop or receive thread not
scheduled for that consumer's margin of 40 ms (`period_max_us` ≥ 40 ms, or
`can_rx_gap_max_us` ≥ 40 ms beyond the thread's 20 ms receive wait) — is excused and
replaced, up to a bound. The last of those was seen in CI: one loop cycle of 62.0 ms whose
thread CPU reading equalled its wall time, ehactl's heartbeat 66.3 ms apart at the hub, the
devices' heartbeats at most 21.1 ms apart there and the sleeper late by 3.5 ms, and ehactl's
consumer tripped on the transducer (a whole-process stop of ehactl for 62 ms, SIGSTOP /
SIGCONT, does not trip it: 3 of 3; its receive thread's gap was not reported then). An
earlier one was seen on this 2-core VM running the suite: a 108 ms gap of ehactl's heartbeat
at the hub, one cycle of 91.4 ms whose thread CPU reading equalled its wall time (the reading ran ahead of the wall clock 59 times
in that run, `exec_cpu_clamped`, so on this VM it cannot tell the host not running the vCPU
from ehactl's own work), while this process's sleeper overslept 4 ms. This excuse would also
hide a cycle of ehactl's that really spends that long: no other test bounds a CAN cycle's
execution time, so every excused run is listed with its figures, and ten clean runs are still
required. Any other trip fails the test, above all a device's loss
of ehactl's heartbeat (EMCY) while the hub relayed it in time, or while the hub and the
devices ran and ehactl's heartbeat was late: before ehactl timed its heartbeat on the clock,
a loop that skipped deadlines stretched 20 ms of loop time to 51–110 ms of wall time and 5 of
6 demo runs ended that way on an idle machine (BENCHMARKS.md "CAN demo")."""
import json
import os
import signal
import subprocess
import threading
import time

import can
import pytest
from mcap.reader import make_reader

from canhub import BIN, hub
from simrig import BOOM, REPO, bus_url, devices, require_bindings

require_bindings()

RUNS = 10          # clean runs required
ATTEMPTS = 24      # bound on runs, excused ones included
DURATION_S = 0.5   # s per run (plus ≈ 0.3 s of start-up)
# the shipped config's [canopen] defaults (crates/types/src/canopen.rs)
PRODUCER_S = 0.020          # master_heartbeat_ms and heartbeat_ms
MASTER_CONSUMER_S = 0.060   # heartbeat_timeout_ms: ehactl's consumer of the devices
DEVICE_CONSUMER_S = 0.100   # device_heartbeat_timeout_ms: the devices' consumer of ehactl
MAX_PDO_AGE_S = 0.050       # max_pdo_age_syncs (50) SYNC periods of 1 ms
STALL_S = MASTER_CONSUMER_S - PRODUCER_S  # the scheduling margin the smaller consumer leaves
RX_WAIT_S = 0.020           # ehactl's receive thread blocks this long for a frame (RX_WAIT)
OWN_CONSUMER = "heartbeat lost (consumer timeout)"  # ehactl's trip on a device's silence


class Sleeper:
    """A 1 ms sleep loop; its largest oversleep in a window is the machine's stall."""

    def __init__(self):
        self.worst = 0.0
        self.stop = threading.Event()
        self.t = threading.Thread(target=self._run, daemon=True)
        self.t.start()

    def _run(self):
        while not self.stop.is_set():
            t0 = time.monotonic()
            time.sleep(0.001)
            self.worst = max(self.worst, time.monotonic() - t0 - 0.001)

    def take(self):
        w, self.worst = self.worst, 0.0
        return w


class HubStamps(can.Listener):
    """The hub's receive stamps of the heartbeats, SYNC and the transducer's TPDO."""

    IDS = (0x701, 0x720, 0x730, 0x080, 0x1A0)

    def __init__(self):
        self.lock = threading.Lock()
        self.ts = {i: [] for i in self.IDS}

    def on_message_received(self, msg):
        if msg.arbitration_id in self.ts:
            with self.lock:
                self.ts[msg.arbitration_id].append(msg.timestamp)

    def take(self):
        with self.lock:
            ts, self.ts = self.ts, {i: [] for i in self.IDS}
        return ts


def device_lateness(ts):
    """The devices' own lateness in one run, at the hub (s): largest gap between heartbeats
    from the first to the last SYNC, and largest delay from SYNC k to the k-th TPDO."""
    sy = ts[0x080]
    if not sy:
        return 0.0, 0.0
    gap = 0.0
    for c in (0x720, 0x730):
        hb = [t for t in ts[c] if sy[0] <= t <= sy[-1]]
        gap = max([gap] + [b - a for a, b in zip(hb, hb[1:])])
    n = min(len(sy), len(ts[0x1A0]))
    answer = max([0.0] + [ts[0x1A0][k] - sy[k] for k in range(n)])
    return gap, answer


def silence_at_trip(path):
    """The silence ehactl's consumer measured when it tripped (from the run's /events)."""
    try:
        with open(path, "rb") as f:
            for _, ch, msg in make_reader(f).iter_messages(topics=["/events"]):
                e = json.loads(msg.data)
                if e.get("kind") == "can_bus" and OWN_CONSUMER in e.get("channel", ""):
                    return f", silent {e['value'] * 1e3:.1f} ms by ehactl's consumer"
    except (OSError, ValueError) as e:
        return f", log unreadable: {e}"
    return ", no consumer event in the log"


def test_the_documented_can_demo_runs_ten_times_without_a_trip(tmp_path):
    sleeper = Sleeper()
    clean, excused, failed = 0, [], []
    with hub() as (_, port), devices(port, tmp_path, config=BOOM) as dev:
        stamps = HubStamps()
        bus = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0",
                      tcp_tune=True)
        notifier = can.Notifier(bus, [stamps], timeout=0.05)
        try:
            for i in range(ATTEMPTS):
                if clean >= RUNS:
                    break
                stamps.take()
                sleeper.take()
                t0 = time.time()
                p = subprocess.run(
                    [BIN, "run", BOOM, "--hal", "canopen", "--bus", bus_url(port), "--json",
                     "--duration", str(DURATION_S), "--out", str(tmp_path / f"demo{i}.mcap")],
                    capture_output=True, text=True, timeout=60, cwd=str(REPO))
                t1 = time.time()
                stall = sleeper.take()
                ts = stamps.take()
                hb_gap, answer = device_lateness(ts)
                last_sync = ts[0x080][-1] if ts[0x080] else t1
                hb = ts[0x701]
                master_gap = max([0.0] + [b - a for a, b in zip(hb, hb[1:])])
                assert "panicked" not in p.stderr, p.stderr
                lines = [ln for ln in p.stdout.splitlines() if ln.strip()]
                summary = json.loads(lines[-1]) if lines else {}
                trip = summary.get("trip") if lines else p.stderr[-500:]
                # ehactl's own measure of a stall: the longest time between two cycle starts
                # (`period_max_us`), with the most thread CPU time one cycle read
                # (`exec_cpu_max_us`) and how often that reading ran ahead of the wall clock
                # (`exec_cpu_clamped`)
                loop_gap = summary.get("period_max_us", 0.0) * 1e-6
                loop_cpu = summary.get("exec_cpu_max_us", float("nan")) * 1e-6
                clamped = summary.get("exec_cpu_clamped")
                # the receive thread's longest time between two looks at the bus
                rx_gap = summary.get("can_rx_gap_max_us", 0.0) * 1e-6
                own_trip = OWN_CONSUMER in str(trip)
                # the devices' loss of ehactl's heartbeat while this run's loop ran: silent
                # since after this run started, detected before its last SYNC (not the loss
                # that follows the end of every run, detected up to 0.1 s into the next)
                lost = [e for e in dev.events("heartbeat-lost")
                        if e.get("producer") == 1 and e["t_wall"] - e["silent_s"] >= t0
                        and e["t_wall"] <= last_sync]
                what = (f"run {i}: exit {p.returncode}, trip {trip!r}, devices lost ehactl's "
                        f"heartbeat: {[(round(e['t_wall'] - t0, 3), round(e['silent_s'], 3)) for e in lost]} (at, silent s), last SYNC {last_sync - t0:.3f} s, sleeper "
                        f"overslept {stall * 1e3:.1f} ms, device heartbeat gap "
                        f"{hb_gap * 1e3:.1f} ms, SYNC answer {answer * 1e3:.1f} ms, ehactl's heartbeat "
                        f"gap {master_gap * 1e3:.1f} ms at the hub, ehactl's longest cycle "
                        f"period {loop_gap * 1e3:.1f} ms (most thread CPU read in a cycle "
                        f"{loop_cpu * 1e3:.2f} ms, CPU readings above the wall clock: "
                        f"{clamped}), receive thread's longest gap {rx_gap * 1e3:.1f} ms"
                        f"{silence_at_trip(tmp_path / f'demo{i}.mcap') if own_trip else ''}")
                # The loop queues ehactl's heartbeat: a loop that started no cycle for the
                # devices' margin silences it whatever the heartbeat timing does.
                loop_not_run = loop_gap >= DEVICE_CONSUMER_S - PRODUCER_S
                # ehactl's own consumer judges silence in the loop from what its receive
                # thread took in: either thread not scheduled for that consumer's margin
                own_stall = own_trip and (loop_gap >= STALL_S or rx_gap - RX_WAIT_S >= STALL_S)
                if p.returncode == 0 and not lost:
                    clean += 1
                elif lost and master_gap < DEVICE_CONSUMER_S - PRODUCER_S:
                    failed.append(what)  # the devices lost a heartbeat the hub relayed in time
                elif (lost and stall < STALL_S and hb_gap <= MASTER_CONSUMER_S
                      and answer <= MAX_PDO_AGE_S and not loop_not_run):
                    failed.append(what)  # ehactl silent while the hub and the devices ran
                elif (stall >= STALL_S or hb_gap > MASTER_CONSUMER_S
                      or answer > MAX_PDO_AGE_S or loop_not_run or own_stall):
                    excused.append(what)  # this machine, the hub, the devices or ehactl's
                    # loop thread were not scheduled
                else:
                    failed.append(what)
        finally:
            notifier.stop()
            bus.shutdown()
            sleeper.stop.set()
    assert not failed, "\n".join(failed + ["excused:"] + excused)
    if clean < RUNS:
        pytest.skip(f"machine too loaded: {clean} clean runs in {ATTEMPTS}; every other run "
                    "came with a measured stall or late device:\n" + "\n".join(excused))


STOP_S = 0.070      # s: ehactl stopped (SIGSTOP … SIGCONT), below the devices' 80 ms margin
STOP_AT_S = 1.2     # s after the spawn: within the loop (start-up takes ≈ 0.3 s)


def test_a_stopped_ehactl_reports_the_stall_of_its_loop_and_receive_thread(tmp_path):
    """Both stall figures of the summary measure what they name: ehactl stopped whole for
    70 ms in the loop shows a loop cycle period and a receive-thread gap of at least 70 ms."""
    with hub() as (_, port), devices(port, tmp_path, config=BOOM):
        p = subprocess.Popen(
            [BIN, "run", BOOM, "--hal", "canopen", "--bus", bus_url(port), "--json",
             "--duration", "2.0", "--out", str(tmp_path / "stopped.mcap")],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=str(REPO))
        time.sleep(STOP_AT_S)
        os.kill(p.pid, signal.SIGSTOP)
        time.sleep(STOP_S)
        os.kill(p.pid, signal.SIGCONT)
        out, err = p.communicate(timeout=60)
    assert "panicked" not in err, err
    summary = json.loads([ln for ln in out.splitlines() if ln.strip()][-1])
    if summary["startup_s"] > STOP_AT_S - 0.2:
        pytest.skip(f"start-up took {summary['startup_s']:.2f} s: the stop may not have hit the loop")
    assert summary["period_max_us"] * 1e-6 >= STOP_S, summary
    assert summary["can_rx_gap_max_us"] * 1e-6 >= STOP_S, summary
