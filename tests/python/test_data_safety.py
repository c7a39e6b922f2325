"""No lost or overwritten file: `ehactl recover` keeps every intact chunk around a bad one,
`diagnose --out` never writes over an input or a file it did not write, `run --out` is
locked against a second writer and never a hard link to the config, a full disk and a file
size limit end a run cleanly. Every test here failed before the fix it covers.

Damaged logs are made from real `ehactl run` logs; the expected counts are computed here,
independently of ehactl (lz4 decompression and record walking by this file), and every
recovered file is read back by the official `mcap` reader with CRCs validated."""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import time
import zlib
from pathlib import Path

import lz4.frame
import pytest
from mcap.reader import make_reader
from mcap.records import ChunkIndex

REPO = Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))
RIG = REPO / "configs" / "diagnose_testrig.toml"
FORCE = REPO / "configs" / "sahu2022_force.toml"
SJ = REPO / "tests" / "data" / "measured" / "sjoberg"
SJ_CONFIG = REPO / "configs" / "sjoberg1995_actuator.toml"


def ehactl(*args: str, timeout: float = 300, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([BIN, *map(str, args)], capture_output=True, text=True, timeout=timeout, **kw)


# --- recover: every intact chunk, honest counts, every compression --------------------------

def _log(tmp: Path, name: str = "log.mcap", extra: str = "") -> Path:
    cfg = tmp / "rig.toml"
    cfg.write_text(RIG.read_text() + extra)
    out = tmp / name
    r = ehactl("run", cfg, "--duration", "1", "--out", out)
    assert r.returncode == 0, r.stderr
    return out


def _chunk_indexes(data: bytes) -> list[ChunkIndex]:
    reader = make_reader(io.BytesIO(data))
    return sorted(reader.get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)


def _chunk_parts(data: bytes, ci: ChunkIndex) -> dict:
    """Fields of the Chunk record at `ci` (MCAP spec, "Chunk (op=0x06)"), parsed here."""
    at = ci.chunk_start_offset
    assert data[at] == 0x06
    (length,) = struct.unpack_from("<Q", data, at + 1)
    body = at + 9
    usize, crc, clen = struct.unpack_from("<QII", data, body + 16)
    comp = data[body + 32: body + 32 + clen].decode()
    (csize,) = struct.unpack_from("<Q", data, body + 32 + clen)
    rec = body + 32 + clen + 8
    return dict(at=at, length=length, body=body, usize=usize, crc=crc, comp=comp, csize=csize, rec=rec)


def _messages_in_chunk(data: bytes, ci: ChunkIndex) -> int:
    p = _chunk_parts(data, ci)
    stored = data[p["rec"]: p["rec"] + p["csize"]]
    plain = lz4.frame.decompress(stored) if p["comp"] == "lz4" else stored
    n, q = 0, 0
    while q < len(plain):
        op = plain[q]
        (ln,) = struct.unpack_from("<Q", plain, q + 1)
        n += op == 0x05
        q += 9 + ln
    return n


def _count_messages(path: Path) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False))


def _recover(tmp: Path, data: bytes, name: str) -> tuple[dict, Path]:
    bad = tmp / f"{name}.mcap"
    bad.write_bytes(data)
    fixed = tmp / f"{name}.recovered.mcap"
    r = ehactl("recover", bad, fixed, "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    total = sum(rep["messages"].values())
    assert rep.setdefault("messages_total", total) == total
    # The recovered file is valid for the official reader and holds what was reported.
    assert _count_messages(fixed) == rep["messages_total"], rep
    return rep, fixed


def _data_end(data: bytes) -> int:
    """Offset of the DataEnd record (where a killed run's file would end, plus one chunk)."""
    reader = make_reader(io.BytesIO(data))
    cis = _chunk_indexes(data)
    last = cis[-1]
    p = last.chunk_start_offset + last.chunk_length
    # message index records follow the chunk; walk to the DataEnd opcode.
    while data[p] != 0x0F:
        (ln,) = struct.unpack_from("<Q", data, p + 1)
        p += 9 + ln
    del reader
    return p


@pytest.fixture(scope="module")
def lz4_log(tmp_path_factory) -> bytes:
    tmp = tmp_path_factory.mktemp("lz4log")
    return _log(tmp).read_bytes()


def _expect_one_dropped(rep: dict, data: bytes, k: int, indexed: bool = True) -> None:
    cis = _chunk_indexes(data)
    total = sum(_messages_in_chunk(data, c) for c in cis)
    lost = _messages_in_chunk(data, cis[k])
    assert len(cis) >= 8, "the test log should have about 10 chunks"
    assert rep["chunks"] == len(cis) - 1 and rep["bad_chunks"] == 1, rep
    assert rep["messages_total"] == total - lost, (rep["messages_total"], total, lost)
    if indexed:
        assert rep["chunks_indexed"] == len(cis)


@pytest.mark.parametrize("k", [0, 1])
def test_recover_keeps_every_chunk_after_a_flipped_byte(tmp_path: Path, lz4_log: bytes, k: int) -> None:
    data = bytearray(lz4_log)
    p = _chunk_parts(data, _chunk_indexes(lz4_log)[k])
    data[p["rec"] + p["csize"] // 2] ^= 0x40
    rep, _ = _recover(tmp_path, bytes(data), f"flip{k}")
    _expect_one_dropped(rep, lz4_log, k)
    assert rep["was_complete"]


@pytest.mark.parametrize("cut", [False, True], ids=["complete", "killed"])
def test_recover_resyncs_after_a_bad_chunk_length(tmp_path: Path, lz4_log: bytes, cut: bool) -> None:
    data = bytearray(lz4_log)
    p = _chunk_parts(data, _chunk_indexes(lz4_log)[1])
    struct.pack_into("<Q", data, p["at"] + 1, p["length"] + 1000)  # still inside the file
    if cut:
        # A killed run: no summary, no chunk index; only the records' own framing is left.
        data = data[: _data_end(lz4_log)]
    rep, _ = _recover(tmp_path, bytes(data), f"len_{cut}")
    _expect_one_dropped(rep, lz4_log, 1, indexed=not cut)
    assert rep["skipped_bytes"] > 0


def test_recover_drops_a_chunk_with_a_wrong_uncompressed_size(tmp_path: Path, lz4_log: bytes) -> None:
    data = bytearray(lz4_log)
    p = _chunk_parts(data, _chunk_indexes(lz4_log)[1])
    struct.pack_into("<Q", data, p["body"] + 16, p["usize"] + 7)
    rep, _ = _recover(tmp_path, bytes(data), "usize")
    _expect_one_dropped(rep, lz4_log, 1)


def test_recover_drops_a_chunk_with_a_broken_record_and_a_valid_crc(tmp_path: Path) -> None:
    # Uncompressed chunks, so the chunk keeps its size when its records are changed.
    log = _log(tmp_path, "plain.mcap", "\n[log]\ncompression = \"none\"\n").read_bytes()
    data = bytearray(log)
    ci = _chunk_indexes(log)[1]
    p = _chunk_parts(data, ci)
    assert p["comp"] == ""
    # The first inner record claims more bytes than the chunk holds; the CRC is made valid.
    struct.pack_into("<Q", data, p["rec"] + 1, p["csize"] * 2)
    plain = bytes(data[p["rec"]: p["rec"] + p["csize"]])
    struct.pack_into("<I", data, p["body"] + 24, zlib.crc32(plain))
    rep, _ = _recover(tmp_path, bytes(data), "inner")
    _expect_one_dropped(rep, log, 1)


def test_recover_reads_zstd_chunks_of_the_official_writer(tmp_path: Path) -> None:
    from mcap.writer import CompressionType, Writer

    path = tmp_path / "z.mcap"
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=4096)
        w.start(profile="", library="test")
        s = w.register_schema(name="S", encoding="jsonschema", data=b"{}")
        c = w.register_channel(topic="/z", message_encoding="json", schema_id=s)
        for i in range(2000):
            w.add_message(channel_id=c, log_time=i * 1000, publish_time=i * 1000, sequence=i,
                          data=json.dumps({"i": i, "pad": "x" * (i % 50)}).encode())
        w.finish()
    data = path.read_bytes()
    cis = _chunk_indexes(data)
    assert len(cis) > 3 and all(c.compression == "zstd" for c in cis)
    rep, fixed = _recover(tmp_path, data, "zstd_whole")
    assert rep["messages_total"] == 2000 and rep["chunks"] == len(cis) and rep["bad_chunks"] == 0, rep
    with open(fixed, "rb") as f:
        seqs = [m.sequence for _, _, m in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False)]
    assert seqs == list(range(2000))
    # Cut inside the last chunk: every chunk before it is kept.
    last = cis[-1]
    rep, _ = _recover(tmp_path, data[: last.chunk_start_offset + 20], "zstd_cut")
    assert rep["stopped_early"] and rep["chunks"] == len(cis) - 1, rep
    assert 0 < rep["messages_total"] < 2000


def test_recover_names_a_compression_it_cannot_read(tmp_path: Path, lz4_log: bytes) -> None:
    data = bytearray(lz4_log)
    p = _chunk_parts(data, _chunk_indexes(lz4_log)[1])
    data[p["body"] + 32: p["body"] + 35] = b"lzx"  # same length as "lz4"
    bad = tmp_path / "lzx.mcap"
    bad.write_bytes(bytes(data))
    r = ehactl("recover", bad, tmp_path / "lzx.recovered.mcap")
    assert r.returncode == 0, r.stderr
    assert "`lzx`" in r.stderr and "cannot read" in r.stderr, r.stderr
    assert "1 dropped" in r.stdout, r.stdout


# --- run --out: never the config by another name, one writer at a time --------------------

def test_run_out_hard_link_to_the_config_is_refused(tmp_path: Path) -> None:
    cfg = tmp_path / "c.toml"
    text = FORCE.read_text()
    cfg.write_text(text)
    hard = tmp_path / "hard.mcap"
    os.link(cfg, hard)
    r = ehactl("run", cfg, "--duration", "0.05", "--out", hard, "--force")
    assert r.returncode == 2, r.stderr
    assert "config being run" in r.stderr and str(hard) in r.stderr, r.stderr
    assert cfg.read_text() == text


def test_second_run_to_the_same_out_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "same.mcap"
    first = subprocess.Popen([BIN, "run", str(FORCE), "--realtime", "--duration", "1.5", "--out", str(out), "--json"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.monotonic()
        while not (out.exists() and out.stat().st_size > 0):
            assert time.monotonic() - t0 < 10, "the first run did not start its log"
            time.sleep(0.02)
        time.sleep(0.3)
        second = ehactl("run", FORCE, "--duration", "0.2", "--out", out, "--json")
        assert second.returncode == 1, second.stderr
        assert str(out) in second.stderr and "another" in second.stderr, second.stderr
        assert second.stdout.strip() == "" or json.loads(second.stdout)["exit_code"] == 1
    finally:
        so, se = first.communicate(timeout=60)
    assert first.returncode == 0, se
    cycles = json.loads(so)["cycles"]
    with open(out, "rb") as f:
        seqs = [m.sequence for _, _, m in make_reader(f, validate_crcs=True).iter_messages(topics=["/control"], log_time_order=False)]
    assert seqs == list(range(cycles)), (len(seqs), cycles)


# --- run: file-size limit and full disk end the run cleanly, with --json's object ----------

def _fsize_limit(limit: int):
    import resource

    def pre():  # in the child before exec; SIGXFSZ keeps its default (death) unless ehactl ignores it
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return pre


def test_run_under_a_file_size_limit_is_a_log_failure_not_a_signal(tmp_path: Path) -> None:
    out = tmp_path / "big.mcap"
    r = subprocess.run([BIN, "run", str(FORCE), "--duration", "600", "--out", str(out), "--json"],
                       capture_output=True, text=True, timeout=120, preexec_fn=_fsize_limit(2_000_000))
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert "File too large" in r.stderr and "safe command" in r.stderr, r.stderr
    obj = json.loads(r.stdout)
    assert obj["exit_code"] == 1 and "File too large" in obj["error"] and obj["mcap"] == str(out)


@pytest.fixture
def tiny_fs(tmp_path: Path):
    """A 256 KiB tmpfs: a real full disk (ENOSPC). Needs root (mount); skipped otherwise."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_run_json_on_a_full_disk_prints_its_object(tiny_fs: Path) -> None:
    out = tiny_fs / "run.mcap"
    r = ehactl("run", FORCE, "--duration", "600", "--out", out, "--json", timeout=120)
    assert r.returncode == 1, r.stderr
    assert "No space left on device" in r.stderr, r.stderr
    obj = json.loads(r.stdout)
    assert obj["exit_code"] == 1 and "No space left" in obj["error"], obj


# --- diagnose --out: never over an input or the user's files; atomic files -----------------

def _tree(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


def test_diagnose_never_writes_over_its_data(tmp_path: Path) -> None:
    d1 = tmp_path / "d1"
    d1.mkdir()
    data = d1 / "traces.csv"
    data.write_bytes((SJ / "estimation.csv").read_bytes())
    before = _tree(d1)
    for extra in ([], ["--force"]):
        r = ehactl("diagnose", "--config", SJ_CONFIG, "--data", data, "--out", d1, *extra)
        assert r.returncode == 2, r.stderr
        assert "never writes over its inputs" in r.stderr and "--data" in r.stderr, r.stderr
        assert _tree(d1) == before


def test_diagnose_never_writes_over_a_hard_link_to_its_data(tmp_path: Path) -> None:
    data = tmp_path / "est.csv"
    data.write_bytes((SJ / "estimation.csv").read_bytes())
    out = tmp_path / "out"
    out.mkdir()
    os.link(data, out / "traces.csv")
    (out / ".ehactl-diagnose").write_text("traces.csv\n")  # even if a manifest claims it
    r = ehactl("diagnose", "--config", SJ_CONFIG, "--data", data, "--out", out)
    assert r.returncode == 2 and "never writes over its inputs" in r.stderr, r.stderr
    assert data.read_bytes() == (SJ / "estimation.csv").read_bytes()


def test_diagnose_refuses_a_directory_of_the_users_files(tmp_path: Path) -> None:
    out = tmp_path / "notes"
    out.mkdir()
    (out / "report.md").write_text("my own report\n")
    r = ehactl("diagnose", "--config", SJ_CONFIG, "--data", SJ / "estimation.csv", "--out", out)
    assert r.returncode == 2, r.stderr
    assert "did not write" in r.stderr and "report.md" in r.stderr and "--force" in r.stderr, r.stderr
    assert (out / "report.md").read_text() == "my own report\n"


def test_diagnose_second_round_never_overwrites_the_config_it_runs(tmp_path: Path) -> None:
    it = tmp_path / "it"
    r = ehactl("diagnose", "--config", SJ_CONFIG, "--data", SJ / "estimation.csv", "--out", it)
    assert r.returncode == 0, r.stderr
    files = _tree(it)
    assert "extended.toml" in files and "report.md" in files
    assert not [n for n in os.listdir(it) if ".tmp-" in n]
    # Its own directory may be written again (a re-run) …
    r = ehactl("diagnose", "--config", SJ_CONFIG, "--data", SJ / "estimation.csv", "--out", it)
    assert r.returncode == 0, r.stderr
    # … but never over the config being run.
    before = _tree(it)
    r = ehactl("diagnose", "--config", it / "extended.toml", "--data", SJ / "estimation.csv", "--out", it)
    assert r.returncode == 2, r.stderr
    assert "--config" in r.stderr and "never writes over its inputs" in r.stderr, r.stderr
    assert _tree(it) == before


def test_diagnose_on_a_full_disk_leaves_no_half_file(tiny_fs: Path) -> None:
    # Leave about 24 KiB free: the report's files do not all fit.
    filler = tiny_fs / "filler"
    with open(filler, "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * 4096)
        except OSError:
            pass
    os.truncate(filler, filler.stat().st_size - 24 * 1024)
    out = tiny_fs / "diag"
    r = ehactl("diagnose", "--config", SJ_CONFIG, "--data", SJ / "estimation.csv", "--out", out, "--json")
    assert r.returncode == 1, r.stderr
    assert "No space left on device" in r.stderr, r.stderr
    names = os.listdir(out) if out.exists() else []
    assert not [n for n in names if ".tmp-" in n], names
    # What is there is whole.
    if (out / "diagnosis.json").exists():
        json.loads((out / "diagnosis.json").read_text())
    for n in names:
        if n.endswith(".csv"):
            text = (out / n).read_text()
            rows = text.splitlines()
            assert text.endswith("\n") and len(rows) > 1, (n, len(text))
            assert {r.count(",") for r in rows} == {rows[0].count(",")}, f"{n} is cut off"
        if n.endswith(".svg"):
            import xml.etree.ElementTree as ET
            ET.parse(out / n)
        if n.endswith(".toml"):
            import tomllib
            tomllib.loads((out / n).read_text())


# --- diagnose: wrong answers with exit 0 ------------------------------------------------------

def test_diagnose_refuses_validate_equal_to_data(tmp_path: Path) -> None:
    data = tmp_path / "e.csv"
    data.write_bytes((SJ / "estimation.csv").read_bytes())
    link = tmp_path / "v.csv"
    os.link(data, link)
    for v in (data, link):
        r = ehactl("diagnose", "--config", SJ_CONFIG, "--data", data, "--validate", v)
        assert r.returncode == 2, r.stderr
        assert "same file as --data" in r.stderr, r.stderr


def test_diagnose_refuses_a_duplicate_column(tmp_path: Path) -> None:
    lines = (SJ / "estimation.csv").read_text().splitlines()
    header = lines[0].split(",")
    assert "p_a" in header
    dup = tmp_path / "dup.csv"
    body = [ln + "," + ln.split(",")[header.index("p_a")] for ln in lines[1:] if ln.strip()]
    dup.write_text(",".join(header + ["p_a"]) + "\n" + "\n".join(body) + "\n")
    r = ehactl("diagnose", "--config", SJ_CONFIG, "--data", dup)
    assert r.returncode == 2, r.stderr
    assert "`p_a` appears twice" in r.stderr, r.stderr


def test_diagnose_refuses_a_log_of_another_rig(tmp_path: Path) -> None:
    log = tmp_path / "force.mcap"
    r = ehactl("run", FORCE, "--duration", "0.3", "--out", log)
    assert r.returncode == 0, r.stderr
    r = ehactl("diagnose", "--config", RIG, "--data", log, "--json")
    assert r.returncode == 2, r.stderr
    # The differing fields, with their values and units.
    assert "cylinder.area_a: logged" in r.stderr and "m²" in r.stderr, r.stderr
    assert "supply.pressure" in r.stderr and "--allow-config-mismatch" in r.stderr, r.stderr
    assert r.stdout.strip() == ""
