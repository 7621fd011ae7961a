"""Bad inputs made on purpose: mutated campaign logs and malformed scenarios.

Used by the robustness tests, the fuzz test and tests/case_table.py (the before/after table of
issue 10). Everything here works on the bytes with the mcap library alone, never with calbench's
reader, so that a mutation cannot be softened by the code under test.

Mutations of a log:
* :func:`rewrite_json` edits JSON messages (``edit(topic, dict) -> dict | bytes | None``; None
  drops the message); ``json.dumps`` writes NaN and Infinity as the non-standard literals a
  careless writer would;
* :func:`flip_bit_in_chunk` flips one bit inside a chunk's compressed data, choosing (seeded) a
  bit after which the chunk still decompresses to different bytes: only the CRC can tell;
* :func:`truncate` cuts the file;
* :func:`drop_topic` removes a channel and its messages.
"""

from __future__ import annotations

import json
import random
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zstandard
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

CHUNK_OPCODE = 0x06
MAGIC = b"\x89MCAP0\r\n"


def _records_tolerant(path: Path) -> list:
    """Records of an MCAP file up to its end or the first unreadable record."""
    out = []
    with open(path, "rb") as f:
        it = StreamReader(f, record_size_limit=1 << 31).records
        while True:
            try:
                out.append(next(it))
            except StopIteration:
                return out
            except Exception:  # noqa: BLE001  a cut-short file: keep what was read
                return out


def rewrite_json(
    src: Path,
    dst: Path,
    edit: Callable[[str, dict], Any] | None = None,
    drop: str | None = None,
    finish: bool = True,
    metadata: Callable[[str, dict], dict] | None = None,
) -> Path:
    """Copy a log record by record; ``edit(topic, message)`` returns the new message (a dict,
    or raw bytes written as they are) or None to drop it; ``metadata(name, record)`` the new
    metadata record. A chunk ends after each pose_done, as in calbench's writer. ``drop``
    removes a topic's channel."""
    topics: dict[int, str] = {}
    schemas: dict[int, Schema] = {}
    sid_map: dict[int, int] = {}
    cid_map: dict[int, int] = {}
    with open(dst, "wb") as f:
        w = Writer(f, chunk_size=16 * 1024, compression=CompressionType.ZSTD)
        for rec in _records_tolerant(Path(src)):
            if isinstance(rec, Header):
                w.start(profile=rec.profile, library=rec.library)
            elif isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                topics[rec.id] = rec.topic
                if rec.topic == drop or rec.id in cid_map:
                    continue
                if rec.schema_id not in sid_map:
                    s = schemas[rec.schema_id]
                    sid_map[rec.schema_id] = w.register_schema(s.name, s.encoding, s.data)
                cid_map[rec.id] = w.register_channel(
                    rec.topic, rec.message_encoding, sid_map[rec.schema_id], dict(rec.metadata)
                )
            elif isinstance(rec, Message):
                if rec.channel_id not in cid_map:
                    continue
                topic = topics[rec.channel_id]
                data = rec.data
                if edit is not None:
                    new = edit(topic, json.loads(data))
                    if new is None:
                        continue
                    data = new if isinstance(new, bytes) else json.dumps(new).encode()
                w.add_message(cid_map[rec.channel_id], rec.log_time, data, rec.publish_time, rec.sequence)
                if topic == "/campaign/pose_done":
                    w.flush()
            elif isinstance(rec, Metadata):
                md = dict(rec.metadata)
                w.add_metadata(rec.name, md if metadata is None else metadata(rec.name, md))
            elif isinstance(rec, Attachment):
                w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
        if finish:
            w.finish()
        else:
            w.flush()
    return Path(dst)


def drop_topic(src: Path, dst: Path, topic: str) -> Path:
    return rewrite_json(src, dst, drop=topic)


def edit_pose(topic: str, pose: int, fn: Callable[[dict], Any]) -> Callable[[str, dict], Any]:
    """An ``edit`` for :func:`rewrite_json` applying ``fn`` to the first message of ``topic``
    for ``pose`` (fn edits in place, or returns a replacement dict or raw bytes)."""
    done = [False]

    def edit(t: str, m: dict):
        if t == topic and m.get("pose") == pose and not done[0]:
            done[0] = True
            out = fn(m)
            return out if isinstance(out, (dict, bytes)) else m
        return m

    return edit


def chunk_spans(data: bytes) -> list[tuple[int, int, int, int]]:
    """(record start, data start, data length, uncompressed size) of every Chunk record."""
    out = []
    pos = len(MAGIC)
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        body = pos + 9
        if body + length > len(data):
            break
        if opcode == CHUNK_OPCODE:
            _, _, usize, _ = struct.unpack_from("<QQQI", data, body)
            clen = struct.unpack_from("<I", data, body + 28)[0]
            rl_at = body + 32 + clen
            rlen = struct.unpack_from("<Q", data, rl_at)[0]
            out.append((pos, rl_at + 8, rlen, usize))
        pos = body + length
    return out


def flip_bit_in_chunk(src: Path, dst: Path, seed: int = 0, chunk: int | None = None) -> Path:
    """Flip one bit of a chunk's compressed records so that the chunk still decompresses (to
    different bytes of the same size). ``chunk`` picks the chunk (default: seeded, not the
    first, which holds the channels). Raises RuntimeError when no such bit is found."""
    data = bytearray(Path(src).read_bytes())
    spans = chunk_spans(bytes(data))
    rng = random.Random(seed)
    order = [chunk] if chunk is not None else rng.sample(range(1, len(spans)), len(spans) - 1)
    for ci in order:
        _, start, n, usize = spans[ci]
        original = zstandard.decompress(bytes(data[start : start + n]), usize)
        bits = rng.sample(range(8 * n), min(8 * n, 4000))
        for b in bits:
            data[start + b // 8] ^= 1 << (b % 8)
            try:
                out = zstandard.decompress(bytes(data[start : start + n]), usize)
            except zstandard.ZstdError:
                out = None
            if out is not None and len(out) == usize and out != original:
                Path(dst).write_bytes(bytes(data))
                return Path(dst)
            data[start + b // 8] ^= 1 << (b % 8)
    raise RuntimeError("no bit flip keeps a chunk decompressible")


def flip_any_bit(src: Path, dst: Path, seed: int) -> Path:
    """Flip one seeded bit anywhere after the magic."""
    data = bytearray(Path(src).read_bytes())
    rng = random.Random(seed)
    b = rng.randrange(8 * len(MAGIC), 8 * len(data))
    data[b // 8] ^= 1 << (b % 8)
    Path(dst).write_bytes(bytes(data))
    return Path(dst)


def truncate(src: Path, dst: Path, n: int) -> Path:
    Path(dst).write_bytes(Path(src).read_bytes()[:n])
    return Path(dst)


def scenario_text(
    n_poses: int = 2,
    repeats: int | None = None,
    extra: str = "",
    poses: list[list[float]] | None = None,
    robot: str | None = None,
) -> str:
    """A small valid scenario (the shipped robot, the paper's truth) with ``n_poses`` poses of
    Table 5, or the given ``poses`` (degrees)."""
    from conftest import MJCF

    table = [
        [0, 0, -30, -45, 30, 135],
        [0, 120, -30, -135, 30, -135],
        [90, 0, 30, -45, -30, -45],
        [180, 35, -30, 135, -30, -45],
        [0, 120, 30, 0, 0, 0],
        [-90, 35, 30, 135, 30, 135],
    ]
    poses = poses if poses is not None else [table[i % len(table)] for i in range(n_poses)]
    text = (
        f'name = "small"\nrobot = "{robot or MJCF}"\nseed = 3\n{extra}\n'
        "[truth]\ncompliance = [0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6]\n"
        "[truth.compensator]\nstiffness = 2.6e6\npreload = 0.83\n"
        "[tracker]\nsigma = 20e-6\nposition = [3.5, -3.5, 3.2]\n"
        "[load]\nmass = 700.0\n"
    )
    for q in poses:
        text += f"\n[[pose]]\nq = {list(q)}\n" + (f"repeats = {repeats}\n" if repeats else "")
    return text


__all__ = [
    "rewrite_json",
    "drop_topic",
    "edit_pose",
    "chunk_spans",
    "flip_bit_in_chunk",
    "flip_any_bit",
    "truncate",
    "scenario_text",
]
