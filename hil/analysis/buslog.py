"""Reading a recorded bus log: every valid frame, and where the damage starts if there is any.

One reader for ``decode``, ``replay`` and the bus load (:mod:`hil.analysis.busload`), so a log
damaged by a kill, a full disk or a flipped bit is judged the same way everywhere: the frames
before the damage are read, the damage is reported where it starts (a frame number for a BLF
file, a line number for a text log: candump ``.log``, ``.asc``, ``.csv``, ``.trc``), and the
caller decides with :meth:`LogReading.check` whether that is an error (exit 3) or, with
``--partial``, a warning line saying how many frames were read and where it stopped.

**BLF** (python-can's and Vector's binary format): a file header (``LOGG``, with the file's size
as its writer closed it) and a sequence of objects, each a ``LOBJ`` header and, for the log
containers that carry the frames, zlib-compressed data with its uncompressed size. Before the
frames are parsed (by python-can's :class:`can.io.BLFReader`), every container is checked whole:
present to its last byte, decompressed without a zlib error (which catches a flipped bit in the
compressed data: zlib's checksum), of the size its header states. The frames of the containers
before the first bad one are read; the file's size must match its header's (a file whose writer
never closed it has a header counting no data: its end is missing). python-can's own reader
would read a truncated container silently and stop (a truncated log replayed as if whole).

**Text logs**: read line by line; the first line python-can's reader cannot parse ("could not
convert string to float") is the damage, by its line number.

**Metadata**: a recording made by the HIL session's recorder (:mod:`hil.session.recorder`) has a
metadata file beside it (:func:`metadata_path`, stamped ``bus-log`` version :data:`METADATA_VERSION`,
read by :func:`read_metadata`); its frame count is compared with the frames read, which finds a
log cut at a frame or line boundary (else undetectable in a text log). Its ``frames_lost`` is the
kernel's count of frames the recorder's socket dropped (``SO_RXQ_OVFL``): frames that were on the
bus but are not in the log, which no reading of the log can find (:func:`frames_lost`).

May raise: :class:`controller.errors.InputError` for a log that cannot be read at all (missing, a
folder, a format python-can does not read) or metadata of an unknown version; damage is raised
only by :meth:`LogReading.check`. May import: python-can, :mod:`controller.errors`.
"""

from __future__ import annotations

import io
import json
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import can

from controller.errors import InputError

# BLF's layout (Vector's binary logging format, as python-can reads and writes it)
_FILE_HEADER = struct.Struct("<4sLBBBBBBBBQQLL8H8H")  # signature, header size, ..., file size, ...
_OBJ_HEADER = struct.Struct("<4sHHLL")  # signature "LOBJ", header size, header version, object size, type
_CONTAINER = struct.Struct("<H6xL4x")  # compression method, uncompressed size
_LOG_CONTAINER, _NO_COMPRESSION, _ZLIB = 10, 0, 2

TEXT_READERS = {".log": "CanutilsLogReader", ".asc": "ASCReader", ".csv": "CSVReader", ".trc": "TRCReader"}
"""python-can's reader of each text format (suffix -> class in :mod:`can.io`)."""


@dataclass(frozen=True)
class Damage:
    """Where a log stops being valid.

    Attributes:
        frame: the 1-based number of the first frame not read (the frames before it are valid).
        line: the 1-based line of a text log where the damage is (None for a binary log).
        reason: what is wrong there, in a few words.
    """

    frame: int
    line: int | None
    reason: str

    @property
    def where(self) -> str:
        return f"line {self.line}" if self.line is not None else f"frame {self.frame}"


class _NotText(ValueError):
    """A line of a text log that is not UTF-8."""


class _CountingLines:
    """A text log read line by line from its binary file (never held whole), counting the lines
    handed out; python-can's text readers iterate it as they would their own file."""

    def __init__(self, binary) -> None:
        self._f = binary
        self.lines = 0
        self.last = ""

    def __iter__(self) -> "_CountingLines":
        return self

    def __next__(self) -> str:
        line = self.readline()
        if not line:
            raise StopIteration
        return line

    def readline(self, size: int = -1) -> str:
        raw = self._f.readline(size)
        if not raw:
            return ""
        self.lines += 1
        try:
            self.last = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            self.last = raw.decode("utf-8", errors="replace")
            raise _NotText(f"not text (a byte that is not UTF-8 at column {exc.start + 1})") from None
        return self.last

    def close(self) -> None:
        self._f.close()


class LogReading:
    """The valid frames of one log, in file order, as an iterator (a long log is never held whole).

    After iterating, :attr:`frames` is how many were read and :attr:`damage` where the log stops
    being valid (None: it is whole). ``expected_frames``: the count the recorder's metadata states,
    if any (fewer frames read is damage: the end is missing).

    Raises:
        InputError: the log is missing, a folder, or of a format python-can does not read.
    """

    def __init__(self, path: str | Path, expected_frames: int | None = None) -> None:
        self.path = Path(path)
        if not str(path).strip():
            raise InputError("the bus log: an empty path")
        if not self.path.exists():
            raise InputError(f"{self.path}: no such log")
        if self.path.is_dir():
            raise InputError(f"{self.path}: a folder, not a bus log")
        suffix = self.path.suffix.lower()
        if suffix != ".blf" and suffix not in TEXT_READERS:
            try:  # the formats python-can reads otherwise (.db, .mf4, compressed): frames counted only
                can.LogReader(str(self.path)).stop()
            except ValueError:
                known = ", ".join([".blf", *TEXT_READERS])
                raise InputError(f"{self.path}: not a bus log format python-can reads ({suffix or 'no suffix'}; "
                                 f"ours are {known})") from None
            except Exception:  # noqa: BLE001 - damaged at its very start: reported by the reading
                pass
        self.expected_frames = expected_frames
        self.frames = 0
        self.damage: Damage | None = None
        self._done = False

    def __iter__(self) -> Iterator[can.Message]:
        if self._done:
            raise RuntimeError("a LogReading is read once")
        self._done = True
        suffix = self.path.suffix.lower()
        if suffix == ".blf":
            source = self._blf()
        elif suffix in TEXT_READERS:
            source = self._text(suffix)
        else:
            source = self._other()
        for msg in source:
            self.frames += 1
            yield msg
        if self.damage is None and self.expected_frames is not None and self.frames < self.expected_frames:
            self.damage = Damage(self.frames + 1, None, f"the log ends after {self.frames} frames; its recorder's "
                                                         f"metadata counts {self.expected_frames}")

    # -- BLF ------------------------------------------------------------------------------------
    def _blf(self) -> Iterator[can.Message]:
        data = self.path.read_bytes()
        good_end, damage = _blf_valid_prefix(data)
        if good_end is None:  # no usable header
            self.damage = Damage(1, None, damage or "not a BLF file")
            return
        try:
            for msg in can.io.BLFReader(io.BytesIO(data[:good_end])):
                yield msg
        except (struct.error, zlib.error, ValueError, EOFError, can.io.blf.BLFParseError) as exc:
            damage = f"unreadable object ({type(exc).__name__}: {_short(exc)})"
        if damage is not None:
            self.damage = Damage(self.frames + 1, None, damage)

    # -- text -----------------------------------------------------------------------------------
    def _text(self, suffix: str) -> Iterator[can.Message]:
        reader_class = getattr(can.io, TEXT_READERS[suffix])
        with open(self.path, "rb") as f:
            lines = _CountingLines(f)
            try:
                for msg in reader_class(lines):
                    yield msg
            except _NotText as exc:
                self.damage = Damage(self.frames + 1, lines.lines, str(exc))
            except (ValueError, IndexError, KeyError, TypeError, AttributeError) as exc:
                # python-can's parsers fail on a junk line with whatever the line makes them raise
                text = " ".join(lines.last.split())
                text = text if len(text) <= 40 else text[:37] + "..."
                self.damage = Damage(self.frames + 1, max(lines.lines, 1), f"not a frame: {text!r} ({_short(exc)})")

    # -- anything else python-can reads ---------------------------------------------------------------
    def _other(self) -> Iterator[can.Message]:
        try:
            reader = can.LogReader(str(self.path))
            for msg in reader:
                yield msg
        except Exception as exc:  # noqa: BLE001 - whatever a damaged file makes that reader raise
            self.damage = Damage(self.frames + 1, None, f"unreadable ({type(exc).__name__}: {_short(exc)})")

    # -- the verdict ----------------------------------------------------------------------------
    def check(self, partial: bool) -> str | None:
        """After iterating: None for a whole log; for a damaged one, raise
        :class:`controller.errors.InputError` (one line: the file, where the damage starts, how many
        frames are valid before it, ``--partial`` to use them) or, with ``partial``, return the
        warning line to print (how many frames were read, where it stopped)."""
        if not self._done:
            raise RuntimeError("check() after reading the log")
        d = self.damage
        if d is None:
            return None
        if not partial:
            raise InputError(f"{self.path}: damaged at {d.where}: {d.reason}; the {self.frames} frames before it "
                             f"are valid (--partial: use them)")
        return f"{self.path}: read {self.frames} frames, stopped at {d.where}: {d.reason}"


METADATA_KIND = "bus-log"
METADATA_VERSION = 1
"""The bus-log metadata's format version: 1 (channel, frames each way, error, and since issue 16
``frames_lost``); 0 is a metadata file without a stamp.

``frames_lost`` was added to version 1 without a new version: a reader that does not know the key
reads every other key as before, and a file written before it is read as "lost: unknown" (the
same as ``null``, which a recorder not on SocketCAN writes), never as 0."""


def metadata_path(log: str | Path) -> Path:
    """The metadata file of the recording at ``log``: the same name with ``.json`` added."""
    log = Path(log)
    return log.with_name(log.name + ".json")


def read_metadata(log: str | Path) -> dict[str, Any] | None:
    """The metadata beside the recording at ``log`` (None if there is none: a log from elsewhere).

    Raises:
        InputError: it is not JSON, not a bus-log metadata file, of a version this reader does
            not know, or its frame count or lost-frame count is not a count.
    """
    from controller.errors import check_stamp

    if not Path(log).name:
        return None
    path = metadata_path(log)
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({' '.join(str(exc).split())})") from None
    check_stamp(data, METADATA_KIND, (0, METADATA_VERSION), source=str(path))
    for key in ("frames", "frames_lost"):
        n = data.get(key)
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 0):
            raise InputError(f"{path}: {key!r} is {n!r}, not a count of frames")
    return data


def frames_lost(metadata: dict[str, Any] | None) -> int | None:
    """The frames the recorder lost (the kernel's drop count, from :func:`read_metadata`'s
    ``metadata``): a count, or None where unknown (no metadata, a file written before the count
    existed, or a recording not made on SocketCAN)."""
    return None if metadata is None else metadata.get("frames_lost")


def _short(exc: BaseException, limit: int = 120) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _blf_valid_prefix(data: bytes) -> tuple[int | None, str | None]:
    """(bytes of ``data`` that hold whole, valid objects, what is wrong after them or None).
    None bytes: not even a file header."""
    if not data:
        return None, "an empty file, not a BLF log"
    if data[:4] != b"LOGG":
        return None, "not a BLF file (no LOGG header)"
    if len(data) < _FILE_HEADER.size:
        return None, f"the file ends inside its header ({len(data)} bytes; truncated)"
    header = _FILE_HEADER.unpack_from(data)
    header_size, file_size = header[1], header[10]
    if header_size < _FILE_HEADER.size:
        return None, f"a damaged BLF header (header size {header_size})"
    if header_size > len(data):
        return None, f"the file ends inside its header ({len(data)} of {header_size} bytes; truncated)"
    pos = good = header_size
    while pos < len(data):
        if len(data) - pos < _OBJ_HEADER.size:
            return good, f"the file ends inside an object header (byte {pos})"
        signature, _, _, obj_size, obj_type = _OBJ_HEADER.unpack_from(data, pos)
        if signature != b"LOBJ":
            return good, f"no object where one should start (byte {pos})"
        if obj_size < _OBJ_HEADER.size + (_CONTAINER.size if obj_type == _LOG_CONTAINER else 0):
            return good, f"an object of impossible size {obj_size} (byte {pos})"
        end = pos + obj_size
        if end > len(data):
            return good, f"the file ends inside a container ({len(data) - pos} of its {obj_size} bytes; truncated)"
        if obj_type == _LOG_CONTAINER:
            method, size = _CONTAINER.unpack_from(data, pos + _OBJ_HEADER.size)
            payload = data[pos + _OBJ_HEADER.size + _CONTAINER.size:end]
            if method == _ZLIB:
                z = zlib.decompressobj()
                try:
                    out = z.decompress(payload)
                except zlib.error as exc:
                    return good, f"a container's compressed data is damaged (zlib: {_short(exc)}; byte {pos})"
                if not z.eof:
                    return good, f"a container's compressed data ends early (byte {pos})"
                n = len(out)
            elif method == _NO_COMPRESSION:
                n = len(payload)
            else:
                return good, f"a container of unknown compression method {method} (byte {pos})"
            if n != size:
                return good, f"a container holds {n} bytes, its header says {size} (byte {pos})"
        pos = end + obj_size % 4  # python-can's padding
        good = min(pos, len(data))
    if file_size == header_size and len(data) > header_size:
        return good, "the recording was never closed by its writer (its header counts no data): its end is missing"
    if file_size != len(data):
        return good, f"the file has {len(data)} bytes, its header says {file_size} (truncated or damaged)"
    return good, None


def read_frames(path: str | Path, partial: bool = False, warn=None,
                expected_frames: int | None = None) -> list[can.Message]:
    """Every valid frame of the log at ``path`` in a list, after :meth:`LogReading.check`
    (``warn(line)`` is called with the warning of a partial read)."""
    reading = LogReading(path, expected_frames)
    frames = list(reading)
    line = reading.check(partial)
    if line is not None and warn is not None:
        warn(line)
    return frames


__all__ = ["Damage", "LogReading", "frames_lost", "read_frames", "read_metadata", "metadata_path", "METADATA_KIND",
           "METADATA_VERSION", "TEXT_READERS"]
