"""The CiA 404 pressure transmitter's EDS (configs/eds/ehactl_pressure_404.eds) served by the
`canopen` package's own `LocalNode` and read by its `RemoteNode` over a virtual bus: the
objects ehactl's CiA 404 profile (crates/canopen/src/cia404.rs) sets and maps exist with the
types it assumes, the start-up step it plans (0x6132:01 = 0) is accepted by a real SDO
server, and TPDO1 as the file maps it carries the process value 0x9130:01 as a little-endian
INTEGER32 (what `Cia404::decode` reads into chamber A's pressure, Pa).

`ehactl run --hal canopen` with this device named in `[[canopen.devices]]` (its pressure in
the MCAP control records' p_a, its heartbeat loss tripping the run) is tested in
tests/python/test_canopen_localnode.py."""
import pathlib
import struct
import time
import uuid

import pytest

canopen = pytest.importorskip("canopen")

EDS = pathlib.Path(__file__).resolve().parents[2] / "configs" / "eds" / "ehactl_pressure_404.eds"
NODE = 64


@pytest.fixture()
def pair():
    channel = f"ehactl-404-{uuid.uuid4().hex}"
    dev_net, master_net = canopen.Network(), canopen.Network()
    dev_net.connect(interface="virtual", channel=channel)
    master_net.connect(interface="virtual", channel=channel)
    dev = canopen.LocalNode(NODE, str(EDS))
    dev_net.add_node(dev)
    remote = canopen.RemoteNode(NODE, str(EDS))
    master_net.add_node(remote)
    remote.received = []
    master_net.subscribe(0x180 + NODE, lambda can_id, data, ts: remote.received.append(bytes(data)))
    yield dev, remote
    dev_net.disconnect()
    master_net.disconnect()


def test_the_device_type_names_profile_404(pair):
    _, remote = pair
    device_type = remote.sdo[0x1000].raw
    assert device_type & 0xFFFF == 404, hex(device_type)


def test_the_planned_decimal_digits_step_is_accepted(pair):
    dev, remote = pair
    assert remote.sdo[0x6132][1].raw == 3        # the file's default
    remote.sdo[0x6132][1].raw = 0                # Cia404::start_steps
    assert struct.unpack("<B", dev.get_data(0x6132, 1))[0] == 0
    assert remote.sdo[0x6132][1].raw == 0


def test_tpdo1_carries_the_process_value_as_int32(pair):
    dev, remote = pair
    od = remote.object_dictionary
    pv = od[0x9130][1]
    assert pv.data_type == canopen.objectdictionary.INTEGER32 and pv.pdo_mappable
    dev.tpdo.read(from_od=True)
    tpdo1 = dev.tpdo[1]
    assert [(v.index, v.subindex, v.length) for v in tpdo1.map] == [(0x9130, 1, 32)]
    pressure_pa = -1_234_567                     # negative: the sign must survive
    dev.sdo[0x9130][1].raw = pressure_pa
    for v in tpdo1.map:  # pack the mapped objects as LocalNode's PDO map does
        v.set_data(dev.get_data(v.index, v.subindex))
    tpdo1.transmit()
    deadline = time.monotonic() + 5.0
    while not remote.received and time.monotonic() < deadline:
        time.sleep(0.01)
    assert remote.received == [struct.pack("<i", pressure_pa)]
