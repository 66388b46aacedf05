"""Point files of a scenario (``.npy``, ``.npz``, ``.ply``) read with what they claim checked before it is read.

Each reader compares the header's shape or vertex count with the bytes the file holds *before* allocating
(a header claiming 10¹² rows is an error, not a 14 TiB allocation), refuses more than :data:`MAX_FILE_POINTS`
rows, and returns an N×k float64 array; the caller checks shape and finiteness. Problems raise
:class:`~factorloc.errors.DatasetError` naming the file.

The PLY reader is the format's own (ASCII and binary, a ``vertex`` element with float ``x y z`` properties):
Open3D's returned uninitialised memory for a file shorter than its header said.
"""

from __future__ import annotations

import io
import math
import zipfile
from pathlib import Path
from typing import IO

import numpy as np

from factorloc.errors import DatasetError

__all__ = ["MAX_FILE_POINTS", "read_npy", "read_npz", "read_ply", "read_points"]

#: The most rows a point file of a scenario may hold (a 3D cloud of 20 million points is 480 MB of float64).
#: Clouds beyond the estimators' own bound are downsampled by them (see ``factorloc._validate.MAX_POINTS``).
MAX_FILE_POINTS = 20_000_000


def _npy_header(f: IO[bytes], where: str) -> tuple[tuple[int, ...], np.dtype]:
    try:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
        elif version in ((2, 0), (3, 0)):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            raise ValueError(f"unknown .npy version {version}")
    except Exception as exc:  # noqa: BLE001 - numpy parses the header with ast/tokenize: ValueError, SyntaxError, TokenError…
        raise DatasetError(f"{where}: not a readable .npy array: {' '.join(str(exc).split())[:200]}") from exc
    if dtype.hasobject or dtype.kind not in "iuf":
        raise DatasetError(f"{where}: must hold numbers, got dtype {dtype}")
    if len(shape) != 2:
        raise DatasetError(f"{where}: must hold an N×k array, got shape {shape}")
    return tuple(int(s) for s in shape), dtype


def _checked_array(f: IO[bytes], available: int, where: str) -> np.ndarray:
    shape, dtype = _npy_header(f, where)
    if shape[0] > MAX_FILE_POINTS:
        raise DatasetError(f"{where}: holds {shape[0]} rows, more than the {MAX_FILE_POINTS} a point file may hold")
    nbytes = math.prod(shape) * dtype.itemsize
    header_end = f.tell()
    if available - header_end != nbytes:
        raise DatasetError(
            f"{where}: its header says shape {shape} of {dtype} ({nbytes} bytes) but the file holds "
            f"{max(available - header_end, 0)} bytes of data"
        )
    data = f.read(nbytes)
    arr = np.frombuffer(data, dtype=dtype).reshape(shape)
    return np.asarray(arr, dtype=np.float64)


def read_npy(path: Path) -> np.ndarray:
    """An N×k array from a ``.npy`` file, its header checked against the file size first."""
    with open(path, "rb") as f:
        return _checked_array(f, path.stat().st_size, repr(str(path)))


def read_npz(path: Path, key: str = "points_m") -> np.ndarray:
    """The array ``key`` of a ``.npz`` file (a zip of ``.npy``), its header checked against its stored size."""
    where = repr(str(path))
    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
            member = f"{key}.npy"
            if member not in names:
                raise DatasetError(f"{where} has no array {key!r} (has {[n.removesuffix('.npy') for n in names]})")
            info = z.getinfo(member)
            with z.open(info) as f:
                head = f.read(min(info.file_size, 65_536 + 128))  # magic + header (≤ 64 KiB by the format)
                buf = io.BytesIO(head)
                shape, dtype = _npy_header(buf, f"{where}[{key}]")
                nbytes = math.prod(shape) * dtype.itemsize
                if shape[0] > MAX_FILE_POINTS or info.file_size - buf.tell() != nbytes:
                    raise DatasetError(
                        f"{where}[{key}]: its header says shape {shape} of {dtype} but the archive stores "
                        f"{info.file_size - buf.tell()} bytes of data (at most {MAX_FILE_POINTS} rows)"
                    )
                rest = head[buf.tell() :] + f.read(nbytes - (len(head) - buf.tell()))
            if len(rest) != nbytes:
                raise DatasetError(f"{where}[{key}]: truncated ({len(rest)} of {nbytes} bytes)")
            return np.asarray(np.frombuffer(rest, dtype=dtype).reshape(shape), dtype=np.float64)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError) as exc:
        if isinstance(exc, DatasetError):
            raise
        raise DatasetError(f"{where}: not a readable .npz archive: {' '.join(str(exc).split())[:200]}") from exc


_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2", "ushort": "u2",
    "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}  # fmt: skip


def _ply_header(data: bytes, where: str) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]], bytes]:
    """(format, elements [(name, count, [(property, numpy type or "list")])], body) of a PLY file's bytes."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise DatasetError(f"{where}: not a PLY file (no 'ply' magic or no 'end_header')")
    nl = data.find(b"\n", end)
    body = data[nl + 1 :] if nl >= 0 else b""
    try:
        header = data[:end].decode("ascii").splitlines()
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{where}: the PLY header is not ASCII") from exc
    fmt, elements = "", []  # [(name, count, [(prop, type)])]
    for line in header[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in _PLY_TYPES:
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        elif words[0] == "property" and elements and words[1] == "list":
            elements[-1][2].append((words[-1], "list"))
        else:
            raise DatasetError(f"{where}: PLY header line not understood: {line[:80]!r}")
    return fmt, elements, body


def read_ply(path: Path) -> np.ndarray:
    """The N×3 ``x y z`` of the ``vertex`` element of a PLY file (ASCII or binary), its count checked."""
    where = repr(str(path))
    fmt, elements, body = _ply_header(path.read_bytes(), where)
    if not elements or elements[0][0] != "vertex":
        raise DatasetError(f"{where}: the first PLY element must be 'vertex'")
    _, count, props = elements[0]
    names = [p[0] for p in props]
    if any(t == "list" for _, t in props) or not {"x", "y", "z"} <= set(names):
        raise DatasetError(f"{where}: the PLY vertex element must have scalar properties x, y, z, got {names}")
    if count > MAX_FILE_POINTS:
        raise DatasetError(f"{where}: says {count} vertices, more than the {MAX_FILE_POINTS} a point file may hold")
    if fmt == "ascii":
        lines = body.split(b"\n")
        rows = [ln.split() for ln in lines[:count]]
        if len(rows) < count or any(len(r) != len(props) for r in rows):
            raise DatasetError(f"{where}: the header says {count} vertices of {len(props)} values; the file holds fewer")
        try:
            table = np.array(rows, dtype=np.float64).reshape(count, len(props))
        except ValueError as exc:
            raise DatasetError(f"{where}: a PLY vertex value is not a number") from exc
        return table[:, [names.index(c) for c in "xyz"]]
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise DatasetError(f"{where}: unknown PLY format {fmt!r}")
    order = "<" if fmt == "binary_little_endian" else ">"
    dtype = np.dtype([(n, order + t) for n, t in props])
    if len(body) < count * dtype.itemsize:
        raise DatasetError(
            f"{where}: the header says {count} vertices ({count * dtype.itemsize} bytes), the file holds {len(body)} bytes"
        )
    rec = np.frombuffer(body, dtype=dtype, count=count)
    return np.stack([rec[c].astype(np.float64) for c in "xyz"], axis=1)


def read_points(path: Path, ncols: int) -> np.ndarray:
    """The points of a ``.npy``, ``.npz`` (array ``points_m``) or ``.ply`` file; PLY keeps x, y for ``ncols`` 2."""
    if path.suffix == ".npy":
        return read_npy(path)
    if path.suffix == ".npz":
        return read_npz(path)
    if path.suffix == ".ply":
        arr = read_ply(path)
        return arr[:, :2] if ncols == 2 else arr
    raise DatasetError(f"{str(path)!r} must be .npy, .npz or .ply")
