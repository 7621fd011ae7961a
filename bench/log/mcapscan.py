"""An MCAP file record by record, telling a file cut short from a damaged one.

Both happen to campaign logs and they call for different answers:

* **cut short** (a crash, SIGKILL, a full disk, power loss): the file simply ends, inside a
  record or between two, without its footer. Everything before the cut is as written, so the
  complete poses are usable (bench/log/read.py reads them and names the rest as lost).
* **damaged** (a flipped bit on a disk or a copy, an edited file): a record is complete but its
  content is wrong. Every check MCAP offers is made, so no damaged byte is read as data:
  - a chunk's CRC of its uncompressed records (a bit flip that still decompresses is caught
    here: zstd frames carry no checksum of their own as mcap writes them);
  - an attachment's CRC (the scenario and the MJCF travel as attachments);
  - the data section CRC in DataEnd (covers the metadata records too) when the writer set it;
  - the summary CRC in the footer;
  - every chunk's MessageIndex records against the messages the chunk holds, and the summary's
    Statistics against all messages read: a record whose opcode was flipped to one a reader
    skips would otherwise vanish without a trace;
  - a record whose length runs past the end of a file that ends with MCAP's closing magic (a
    finished file cannot have been cut).

:func:`scan` yields the records in file order (chunks opened into their records, each followed
by its MessageIndex records), a :class:`Damage` in place of each damaged record, and one
:class:`Cut` last when the file ends before its footer. It does not stop at damage, so a salvage (``calbench recover``) can keep
what follows; a strict reader stops at the first. Unknown opcodes are skipped, as MCAP asks.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import breakup_chunk

from calbench.bench.core import InputError

MAGIC = b"\x89MCAP0\r\n"
MAGIC_TEXT = "an MCAP file (magic bytes 89 4D 43 41 50 30 0D 0A)"
_RECORD_TYPES = {
    Opcode.ATTACHMENT: Attachment,
    Opcode.ATTACHMENT_INDEX: AttachmentIndex,
    Opcode.CHANNEL: Channel,
    Opcode.CHUNK: Chunk,
    Opcode.CHUNK_INDEX: ChunkIndex,
    Opcode.DATA_END: DataEnd,
    Opcode.FOOTER: Footer,
    Opcode.HEADER: Header,
    Opcode.MESSAGE: Message,
    Opcode.MESSAGE_INDEX: MessageIndex,
    Opcode.METADATA: Metadata,
    Opcode.METADATA_INDEX: MetadataIndex,
    Opcode.SCHEMA: Schema,
    Opcode.STATISTICS: Statistics,
    Opcode.SUMMARY_OFFSET: SummaryOffset,
}


@dataclass(frozen=True)
class Damage:
    """A complete record whose content is wrong: ``offset`` is its first byte in the file."""

    offset: int
    record: str  # the record type ("Chunk", "Attachment", ...) or "record"
    why: str

    def __str__(self) -> str:
        return f"{self.record} at byte {self.offset}: {self.why}"


@dataclass(frozen=True)
class At:
    """Yielded before each complete top-level record when asked (``scan(..., marks=True)``): the
    records that follow, up to the next ``At``, are that record or, for a chunk, its content.
    A reader notes where a pose's messages are and reads just those again
    (:func:`scan_span`)."""

    offset: int


@dataclass(frozen=True)
class Cut:
    """The file ends before its footer; ``offset`` is where the readable part ends."""

    offset: int


def _parse(opcode: int, body: bytes) -> Any:
    stream = ReadDataStream(BytesIO(body))
    cls = _RECORD_TYPES[opcode]
    rec = cls.read(stream, len(body)) if cls is Message else cls.read(stream)
    if stream.count > len(body):  # pragma: no cover - ReadDataStream raises first
        raise ValueError("record content longer than its length")
    return rec


def open_mcap(path: str | os.PathLike):
    """Open ``path`` for reading, checking MCAP's opening magic; InputError when it is missing,
    unreadable or not MCAP."""
    path = Path(path)
    try:
        f = open(path, "rb")
    except OSError as e:
        raise InputError(path, "file", "a readable MCAP file", e.strerror or str(e)) from None
    magic = f.read(len(MAGIC))
    if magic != MAGIC:
        f.close()
        raise InputError(path, "file", MAGIC_TEXT, magic.hex(" ") if magic else "an empty file")
    return f


def scan(path: str | os.PathLike, marks: bool = False) -> Iterator[Any]:
    """Records of an MCAP file in order, with :class:`Damage` and :class:`Cut` events (see the
    module docstring), and with ``marks`` an :class:`At` before each record. Raises InputError
    when the file is missing or not MCAP."""
    f = open_mcap(path)
    with f:
        size = os.fstat(f.fileno()).st_size
        f.seek(size - len(MAGIC))
        finished = size >= 2 * len(MAGIC) + 9 and f.read(len(MAGIC)) == MAGIC
        f.seek(len(MAGIC))
        yield from _scan(f, size, finished, marks)


def scan_span(path: str | os.PathLike, first: int, last: int) -> Iterator[Any]:
    """The records of the top-level records from offset ``first`` to offset ``last`` (both
    :attr:`At.offset` values of an earlier scan), chunks opened and their CRCs checked again:
    what a reader that noted where a pose's messages are reads to have them again. A record
    that no longer decodes yields :class:`Damage` (the file changed since)."""
    f = open_mcap(path)
    with f:
        size = os.fstat(f.fileno()).st_size
        f.seek(first)
        for rec in _scan(f, size, False, True, pos=first, whole=False):
            if isinstance(rec, At) and rec.offset > last:
                return
            if isinstance(rec, (Cut, Footer)):
                return
            if not isinstance(rec, (At, MessageIndex)):
                yield rec


def _scan(
    f, size: int, finished: bool, marks: bool = False, pos: int = len(MAGIC), whole: bool = True
) -> Iterator[Any]:
    """The records from ``pos`` (the file positioned there); not ``whole``: a span read from the
    middle of the file, without the data section's CRC."""
    crc = zlib.crc32(MAGIC)  # running CRC of the data section (unused in a span)
    seen: Counter = Counter()  # messages read per channel
    chunk_counts: Counter | None = None  # messages of the chunk just read, for its indexes
    chunk_damaged = False
    stats: Statistics | None = None
    while True:
        head = f.read(9)
        if len(head) < 9:
            yield (
                Damage(pos, "file", "it ends without a footer although it ends with MCAP's closing magic")
                if finished
                else Cut(pos)
            )
            return
        opcode, length = struct.unpack("<BQ", head)
        if length > size - pos - 9:
            if finished:
                yield Damage(pos, "record", f"length {length} runs past the end of the file")
            else:
                yield Cut(pos)
            return
        body = f.read(length)
        if len(body) < length:  # pragma: no cover - the file shrank while read
            yield Cut(pos)
            return
        crc_before = crc
        if whole:
            crc = zlib.crc32(body, zlib.crc32(head, crc))
        here, pos = pos, pos + 9 + length
        if opcode not in _RECORD_TYPES:
            continue  # unknown records are skipped (the MCAP spec)
        if marks:
            yield At(here)
        name = _RECORD_TYPES[opcode].__name__
        try:
            rec = _parse(opcode, body)
        except Exception as e:  # noqa: BLE001  any decoding failure of a complete record
            yield Damage(here, name, f"cannot be decoded ({type(e).__name__}: {e})")
            chunk_counts, chunk_damaged = None, opcode == Opcode.CHUNK
            continue
        if isinstance(rec, Chunk):
            chunk_counts, chunk_damaged = None, False
            try:
                inner = breakup_chunk(rec, validate_crc=True)
            except Exception as e:  # noqa: BLE001  CRC mismatch, bad compression, cut records
                chunk_damaged = True
                yield Damage(here, "Chunk", _chunk_problem(e))
                continue
            chunk_counts = Counter(r.channel_id for r in inner if isinstance(r, Message))
            seen.update(chunk_counts)
            yield from inner
            continue
        if isinstance(rec, MessageIndex):
            if chunk_counts is not None and chunk_counts.get(rec.channel_id, 0) != len(rec.records):
                yield Damage(
                    here,
                    name,
                    f"indexes {len(rec.records)} messages of channel "
                    f"{rec.channel_id} where its chunk holds "
                    f"{chunk_counts.get(rec.channel_id, 0)}",
                )
            elif chunk_counts is None and not chunk_damaged:
                yield Damage(here, name, "indexes a chunk that is not there (a record before it was lost)")
            yield rec  # after a damaged chunk: which channels it held
            continue
        chunk_counts = None
        chunk_damaged = False
        if isinstance(rec, Message):
            seen[rec.channel_id] += 1
        elif isinstance(rec, Attachment):
            stored = struct.unpack("<I", body[-4:])[0]
            if stored and stored != zlib.crc32(body[:-4]):
                yield Damage(here, name, f"CRC mismatch ({rec.name!r})")
                continue
        elif isinstance(rec, DataEnd):
            if whole and rec.data_section_crc and rec.data_section_crc != crc_before:
                yield Damage(
                    here,
                    name,
                    "the data section's CRC does not match (with every "
                    "chunk and attachment intact: a metadata record is "
                    "damaged)",
                )
        elif isinstance(rec, Statistics):
            stats = rec
        elif isinstance(rec, Footer):
            if pos + len(MAGIC) != size:
                yield Damage(here, name, f"a footer {size - pos} bytes before the end of the file")
                return
            yield from _check_summary(f, rec, here, stats, seen)
            yield rec
            return
        yield rec


def _chunk_problem(e: Exception) -> str:
    text = str(e).split("\n")[0][:120]
    if "crc" in text.lower():
        return "CRC mismatch: its records are not the ones written"
    return f"cannot be decompressed or decoded ({type(e).__name__}: {text})"


def _check_summary(f, footer: Footer, here: int, stats: Statistics | None, seen: Counter) -> Iterator[Damage]:
    if not (
        footer.summary_start <= footer.summary_offset_start <= here
        or footer.summary_offset_start == 0
        and footer.summary_start <= here
    ):
        yield Damage(here, "Footer", "its summary offsets point outside the file")
        return
    if footer.summary_crc and footer.summary_start:
        f.seek(footer.summary_start)
        data = f.read(here - footer.summary_start) + struct.pack(
            "<BQQQ", Opcode.FOOTER, 20, footer.summary_start, footer.summary_offset_start
        )
        if zlib.crc32(data) != footer.summary_crc:
            yield Damage(here, "Footer", "the summary's CRC does not match")
            return
    if stats is not None:
        counts = {c: n for c, n in stats.channel_message_counts.items() if n}
        if stats.message_count != sum(seen.values()) or counts != {c: n for c, n in seen.items() if n}:
            yield Damage(
                here,
                "Statistics",
                f"the summary counts {stats.message_count} messages, "
                f"the file holds {sum(seen.values())} readable ones",
            )


__all__ = ["MAGIC", "MAGIC_TEXT", "At", "Damage", "Cut", "scan", "scan_span", "open_mcap"]
