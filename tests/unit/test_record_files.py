"""MCAP files of the recorder: rotation by size and time, latched channels in every part, the
disk budget, reading a file cut short, the recordings list and safe download paths."""

from __future__ import annotations

import json
import os
import random
from pathlib import Path

import pytest
from mcap.reader import make_reader

from curio.core.errors import SetupError
from curio.record.codec import Codec
from curio.record.library import list_recordings, resolve_download
from curio.record.mcap_sink import McapSink
from curio.record.reader import RecordingError, open_recording

CODEC = Codec(1_700_000_000.0)
SCAN = CODEC.spec("/wheels")  # a streamed channel
MAP = CODEC.spec("/map")  # a latched one
EVENTS = CODEC.spec("/events")
S = 1_000_000_000


def sink(tmp_path: Path, **kw: object) -> McapSink:
    args: dict[str, object] = dict(directory=tmp_path, file=None, started_wall_s=1.7e9,
                                   metadata={"k": "v"}, max_file_bytes=10**9, max_file_s=1e9,
                                   max_total_bytes=10**10)
    args.update(kw)
    return McapSink(**args)  # type: ignore[arg-type]


def payload(i: int) -> bytes:
    noise = random.Random(i).random
    return json.dumps({"stamp": i, "positions": [noise() for _ in range(20)]}).encode()


def topics_of(path: Path) -> list[str]:
    return [m.channel for m in open_recording(path).messages()]


def test_rotation_by_time_and_latched_channels_start_every_part(tmp_path: Path) -> None:
    s = sink(tmp_path, max_file_s=10.0)
    s.write(MAP, 0, 0, 1, b'{"map": 1}')
    for i in range(30):  # 30 s of messages at 1 Hz: three parts
        s.write(SCAN, i * S, i * S, i + 2, payload(i))
    s.close()
    assert [p.name for p in s.files] == [f"curio-20231114T221320Z-00{k}.mcap" for k in (1, 2, 3)]
    for path in s.files:
        assert topics_of(path)[0] == "/map", path.name  # each part opens with the map
        rec = open_recording(path)
        assert rec.profile == "curio" and rec.curio["k"] == "v"
    assert sum(topics_of(p).count("/wheels") for p in s.files) == 30


def test_rotation_by_size_and_the_budget_deletes_the_oldest_first(tmp_path: Path) -> None:
    foreign = tmp_path / "keep-me.mcap"
    foreign.write_bytes(b"not ours")
    old = tmp_path / "curio-20200101T000000Z-001.mcap"
    old.write_bytes(b"x" * 30_000)
    os.utime(old, (1, 1))
    s = sink(tmp_path, max_file_bytes=20_000, max_total_bytes=60_000)
    for i in range(600):
        s.write(SCAN, i * S // 10, i * S // 10, i, payload(i))
        if i % 50 == 0:
            s.flush()  # chunks reach the file, so its size grows
    s.close()
    assert len(s.files) >= 3
    assert not old.exists() and foreign.exists()  # oldest own file went, others never
    assert old in s.deleted
    own = [p for p in tmp_path.glob("curio-*.mcap")]
    assert sum(p.stat().st_size for p in own) <= 60_000 + 20_000 + 5_000


def test_single_file_mode_never_rotates(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "run.mcap"
    s = sink(tmp_path, directory=None, file=target, max_file_bytes=1000, max_file_s=1.0)
    for i in range(100):
        s.write(SCAN, i * S, i * S, i, payload(i))
    s.close()
    assert s.files == [target] and len(topics_of(target)) == 100


def test_a_file_cut_short_reads_up_to_its_last_flush(tmp_path: Path) -> None:
    s = sink(tmp_path)
    for i in range(100):
        s.write(SCAN, i * S, i * S, i, payload(i))
        if i == 59:
            s.flush()
    s.flush()
    path = s.files[0]
    whole = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) - 300])  # the last chunk loses its end: as kill -9
    rec = open_recording(cut)
    got = [json.loads(m.data)["stamp"] for m in rec.messages()]
    assert got == list(range(60)) and rec.truncated
    assert rec.curio["k"] == "v"


def test_summary_list_and_download_paths(tmp_path: Path) -> None:
    s = sink(tmp_path)
    for i in range(10):
        s.write(SCAN, (5 + i) * S, i * S, i, payload(i))
    s.write(EVENTS, 20 * S, 15 * S, 11, b'{"stamp": 15, "kind": "collision", "detail": {}}')
    s.close()
    with s.files[0].open("rb") as fh:
        meta = {r.name: r.metadata for r in make_reader(fh).iter_metadata()}
    assert json.loads(meta["curio.summary"]["channels"]) == {"/events": 1, "/wheels": 10}
    crashed = tmp_path / "curio-20231114T221320Z-r2-001.mcap"
    crashed.write_bytes(s.files[0].read_bytes()[:-200])
    (tmp_path / "junk.mcap").write_bytes(b"junk")
    infos = {r.name: r for r in list_recordings(tmp_path)}
    whole = infos[s.files[0].name]
    assert whole.complete and whole.messages == 11 and whole.duration_s == pytest.approx(15.0)
    assert whole.start_s == pytest.approx(5.0) and whole.events == {"collision": 1}
    assert whole.summary == "1 collision" and whole.size_bytes == s.files[0].stat().st_size
    assert not infos[crashed.name].complete and infos[crashed.name].messages >= 10
    assert "junk.mcap" not in infos
    assert resolve_download(tmp_path, s.files[0].name) == s.files[0].resolve()
    for bad in ("../etc/passwd", "/etc/passwd", "a/b.mcap", ".hidden.mcap", "x.txt",
                "missing.mcap", ""):
        with pytest.raises(SetupError):
            resolve_download(tmp_path, bad)
    (tmp_path / "link.mcap").symlink_to("/etc/hostname")
    with pytest.raises(SetupError):
        resolve_download(tmp_path, "link.mcap")


def test_open_recording_names_the_problem(tmp_path: Path) -> None:
    (tmp_path / "text.mcap").write_text("hello")
    for path, why in ((tmp_path / "none.mcap", "no such file"),
                      (tmp_path / "text.mcap", "not an MCAP file"), (tmp_path, "directory")):
        with pytest.raises(RecordingError, match=why):
            open_recording(path)


def test_an_unfinished_file_is_listed_from_its_chunks_without_reading_it_through(
        tmp_path: Path) -> None:
    s = sink(tmp_path)
    for i in range(100):
        s.write(SCAN, (5 + i) * S, i * S, i, payload(i))
        if i in (29, 59):
            s.flush()  # two chunks on disk; the file is still open (being written)
    (info,) = list_recordings(tmp_path, scan=False)
    assert not info.complete and info.messages == 0  # not counted: nothing was decompressed
    assert (info.start_s, info.duration_s) == pytest.approx((5.0, 59.0))
    assert "not read through" in info.summary
    (scanned,) = list_recordings(tmp_path)  # read through: the same span, counted
    assert scanned.messages == 60 and scanned.duration_s == pytest.approx(59.0)
    s.close()


def test_health_reads_the_size_while_the_writer_thread_closes_a_file(tmp_path: Path) -> None:
    """Found by the soak: health (the loop's thread) read the open file's size while the writer
    thread closed it for a rotation — ``tell()`` on a closed file raised, the recorder part
    crashed and took the rover down."""
    s = sink(tmp_path)
    for i in range(20):
        s.write(SCAN, i * S, i * S, i, payload(i))
    s.flush()
    before = s.describe()["bytes_written"]
    assert before > 0
    assert s._fh is not None
    s._fh.close()  # what the writer thread does while health holds the handle
    assert s.describe()["bytes_written"] == before  # its last size seen, no exception
