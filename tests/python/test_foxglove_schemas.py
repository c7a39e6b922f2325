"""What Foxglove needs from an ehactl MCAP log, checked with tools we did not write:

- the JSON channels (/config, /events, /summary, /log) carry real JSON Schemas (fields
  listed) and every message validates against its channel's schema (``jsonschema``);
- /log holds the events as ``foxglove.Log``: field names and level values equal Foxglove's
  own published schema (the ``foxglove-schemas-protobuf`` package's ``Log`` descriptor), and
  every message converts into that protobuf message;
- the Foxglove layout in deploy/foxglove only names topics and fields that exist in the log.
"""

from __future__ import annotations

import json
import re
import subprocess

import jsonschema
import pytest
from mcap.reader import make_reader

from test_mcap_roundtrip import FORCE_CONFIG, REPO, ehactl_bin

LAYOUT = REPO / "deploy" / "foxglove" / "ehactl_layout.json"


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("fx") / "run.mcap"
    r = subprocess.run([str(ehactl_bin()), "run", str(FORCE_CONFIG), "--duration", "0.2", "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    schemas: dict[str, tuple[str, str, str]] = {}
    msgs: dict[str, list[bytes]] = {}
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        for ch in summary.channels.values():
            s = summary.schemas[ch.schema_id]
            schemas[ch.topic] = (s.name, s.encoding, s.data.decode())
        for _s, ch, m in reader.iter_messages():
            msgs.setdefault(ch.topic, []).append(bytes(m.data))
    return {"schemas": schemas, "messages": msgs}


def test_json_channels_have_field_schemas_and_messages_validate(log):
    expect = {"/config": "ehactl.Config", "/events": "ehactl.Event", "/summary": "ehactl.Summary",
              "/log": "foxglove.Log"}
    for topic, name in expect.items():
        sname, enc, text = log["schemas"][topic]
        assert (sname, enc) == (name, "jsonschema")
        schema = json.loads(text)
        jsonschema.Draft202012Validator.check_schema(schema)
        assert len(schema["properties"]) >= 3, (topic, schema)
        assert log["messages"].get(topic), f"no message on {topic}"
        for m in log["messages"][topic]:
            jsonschema.validate(json.loads(m), schema)
    # the config schema lists the registered fields with units
    cfg = json.loads(log["schemas"]["/config"][2])["properties"]["config"]
    bm = cfg["properties"]["fluid"]["properties"]["bulk_modulus"]
    assert bm["type"] == "number" and "(Pa)" in bm["description"]
    ev = json.loads(log["schemas"]["/events"][2])
    assert {"t", "cycle", "severity", "kind", "value", "limit", "unit", "text"} <= set(ev["properties"])


def test_log_channel_is_foxglove_log(log):
    Log_pb2 = pytest.importorskip("foxglove_schemas_protobuf.Log_pb2")
    from google.protobuf.timestamp_pb2 import Timestamp

    desc = Log_pb2.Log.DESCRIPTOR
    levels = {v.name: v.number for v in desc.enum_types_by_name["Level"].values}
    schema = json.loads(log["schemas"]["/log"][2])
    assert set(schema["properties"]) == {f.name for f in desc.fields}
    assert {o["title"]: o["const"] for o in schema["properties"]["level"]["oneOf"]} == levels
    events = [json.loads(m) for m in log["messages"]["/events"]]
    logs = [json.loads(m) for m in log["messages"]["/log"]]
    assert len(logs) == len(events) >= 2  # start and end at least
    sev = {"info": levels["INFO"], "warning": levels["WARNING"], "trip": levels["ERROR"]}
    for ev, lg in zip(events, logs):
        pb = Log_pb2.Log(
            timestamp=Timestamp(seconds=lg["timestamp"]["sec"], nanos=lg["timestamp"]["nsec"]),
            level=lg["level"], message=lg["message"], name=lg["name"], file=lg["file"], line=lg["line"],
        )
        assert pb.level == sev[ev["severity"]]
        assert pb.message == ev["text"]
        assert pb.timestamp.seconds + pb.timestamp.nanos * 1e-9 == pytest.approx(ev["t"], abs=1e-9)


def test_layout_names_only_existing_topics_and_fields(log):
    layout = json.loads(LAYOUT.read_text())
    fields: dict[str, set[str]] = {}
    for topic, (_name, enc, text) in log["schemas"].items():
        if enc == "ros2msg":
            fields[topic] = {ln.split()[1] for ln in text.splitlines() if ln and not ln.startswith("#")}
        else:
            fields[topic] = set(json.loads(text).get("properties", {}))
    fields.setdefault("/timing", set())
    # /timing is written by --realtime runs only; its schema is advertised in every log
    assert "/timing" in log["schemas"]
    used = 0
    for pid, cfg in layout["configById"].items():
        for p in cfg.get("paths", []):
            m = re.fullmatch(r"(/\w+)\.(\w+)", p["value"])
            assert m, p["value"]
            assert m.group(2) in fields[m.group(1)], (pid, p["value"])
            used += 1
        for key in ("topicToRender", "topicPath"):
            if key in cfg:
                assert cfg[key] in log["schemas"], (pid, cfg[key])
    assert used >= 10

    def panels(node):
        if isinstance(node, str):
            return [node]
        return panels(node["first"]) + panels(node["second"])

    assert sorted(panels(layout["layout"])) == sorted(layout["configById"])
