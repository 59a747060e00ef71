"""Versioned, checksummed dataset files: :func:`save` writes a :class:`~offline.data.table.Dataset`
atomically, :func:`load` refuses anything corrupted (the file layout is documented in
:mod:`offline.data.dataset`; docs/design.md §2.4)."""

from __future__ import annotations

import hashlib
import io
import json
import os
import tempfile
import zipfile
from collections.abc import Mapping
from typing import Any

import numpy as np

from offline.data.table import FIELDS, Dataset, Metadata, validate

#: Version of the file layout written by :func:`save`; :func:`load` refuses any other.
FORMAT_VERSION = 1
#: Format name stored in every file's header.
FORMAT_NAME = "mjxrmp.offline.Dataset"
HEADER_MEMBER = "header.json"
# Fixed zip member timestamp: the same dataset always gives the same file bytes.
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


class DatasetFileError(ValueError):
    """A dataset file that cannot be loaded (corrupted, truncated, tampered, other version)."""


def _digest(x: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()


def _total_digest(fields: Mapping[str, Mapping[str, Any]], metadata: Any) -> str:
    """SHA-256 over every field's name, dtype, shape and digest, and the canonical metadata."""
    h = hashlib.sha256()
    for name in FIELDS:
        f = fields[name]
        h.update(f"{name}:{f['dtype']}:{f['shape']}:{f['sha256']};".encode())
    h.update(json.dumps(metadata, sort_keys=True, allow_nan=False).encode())
    return h.hexdigest()


def _header(arrays: Mapping[str, np.ndarray], metadata: Metadata) -> dict[str, Any]:
    fields = {name: {"dtype": arrays[name].dtype.str, "shape": list(arrays[name].shape),
                     "sha256": _digest(arrays[name])} for name in FIELDS}
    return {"format": FORMAT_NAME, "format_version": FORMAT_VERSION, "fields": fields,
            "sha256": _total_digest(fields, metadata.to_dict()), "metadata": metadata.to_dict()}


def save(dataset: Dataset, path: str | os.PathLike) -> str:
    """Write ``dataset`` to ``path`` atomically (see the module docstring); return the path.

    The dataset is validated first. The path is used as given (no suffix is added; ``.npz`` is
    the convention). Parent directories are created.
    """
    validate(dataset)
    path = os.fspath(path)
    arrays = {name: np.ascontiguousarray(np.asarray(x)) for name, x in dataset.arrays().items()}
    header = json.dumps(_header(arrays, dataset.metadata), indent=1, sort_keys=True)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{os.path.basename(path)}.",
                               suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            with zipfile.ZipFile(f, "w", compression=zipfile.ZIP_STORED) as zf:
                zf.writestr(zipfile.ZipInfo(HEADER_MEMBER, _ZIP_DATE), header)
                for name in FIELDS:
                    buf = io.BytesIO()
                    np.lib.format.write_array(buf, arrays[name], allow_pickle=False)
                    zf.writestr(zipfile.ZipInfo(f"{name}.npy", _ZIP_DATE), buf.getvalue())
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def load(path: str | os.PathLike) -> Dataset:
    """Read a dataset written by :func:`save`, refusing anything corrupted.

    Returns NumPy arrays (``jax.device_put`` the result to use it on an accelerator). Raises
    :class:`DatasetFileError` (a ``ValueError``) naming the file and the problem: not a zip
    archive or truncated, missing/unreadable header, another format or version, missing or
    unexpected members, zip CRC error, dtype/shape differing from the header, SHA-256
    mismatch, or invalid contents (:func:`validate`); ``FileNotFoundError`` if it is absent.
    """
    path = os.fspath(path)

    def fail(msg: str) -> DatasetFileError:
        return DatasetFileError(f"dataset file {path!r}: {msg}")

    if not os.path.exists(path):
        raise FileNotFoundError(f"dataset file {path!r} does not exist")
    try:
        zf = zipfile.ZipFile(path, "r")
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise fail(f"not a readable zip archive (truncated or corrupted?): {e}") from e
    with zf:
        members = set(zf.namelist())
        if HEADER_MEMBER not in members:
            raise fail(f"no {HEADER_MEMBER} member (not written by offline.data.dataset.save?)")
        try:
            header = json.loads(zf.read(HEADER_MEMBER).decode("utf-8"))
        except (zipfile.BadZipFile, OSError, EOFError, UnicodeDecodeError, ValueError) as e:
            raise fail(f"unreadable {HEADER_MEMBER} (corrupted?): {e}") from e
        if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
            fmt = header.get("format") if isinstance(header, dict) else None
            raise fail(f"header format is {fmt!r}, expected {FORMAT_NAME!r}")
        if header.get("format_version") != FORMAT_VERSION:
            raise fail(f"format_version {header.get('format_version')!r} is not supported "
                       f"(this code reads version {FORMAT_VERSION})")
        fields = header.get("fields")
        if not isinstance(fields, dict) or set(fields) != set(FIELDS):
            got = sorted(fields) if isinstance(fields, dict) else fields
            raise fail(f"header lists fields {got}, expected {sorted(FIELDS)}")
        for name in FIELDS:
            f = fields[name]
            if not (isinstance(f, dict) and {"dtype", "shape", "sha256"} <= set(f)):
                raise fail(f"header entry for field {name!r} lacks dtype/shape/sha256: {f!r}")
        try:
            total = _total_digest(fields, header.get("metadata"))
        except (TypeError, ValueError) as e:
            raise fail(f"header metadata is not canonical JSON: {e}") from e
        if header.get("sha256") != total:
            raise fail("header checksum mismatch (the header or metadata was modified or "
                       "corrupted)")
        expected = {HEADER_MEMBER} | {f"{n}.npy" for n in FIELDS}
        if members - expected:
            raise fail(f"unexpected member(s) {sorted(members - expected)}")
        arrays = {}
        for name in FIELDS:
            member, f = f"{name}.npy", fields[name]
            if member not in members:
                raise fail(f"field {name!r} is missing (no member {member!r})")
            try:
                raw = zf.read(member)  # checks the zip CRC-32
                x = np.lib.format.read_array(io.BytesIO(raw), allow_pickle=False)
            except (zipfile.BadZipFile, OSError, EOFError, ValueError) as e:
                raise fail(f"field {name!r} is corrupted ({e})") from e
            if x.dtype.str != f["dtype"] or list(x.shape) != list(f["shape"]):
                raise fail(f"field {name!r} has dtype {x.dtype.str} and shape "
                           f"{list(x.shape)}, the header says {f['dtype']} and {f['shape']}")
            if _digest(x) != f["sha256"]:
                raise fail(f"field {name!r} SHA-256 checksum mismatch (the array data was "
                           f"modified or corrupted)")
            arrays[name] = x
    try:
        ds = Dataset(**arrays, metadata=Metadata(header["metadata"]))
        return validate(ds, name=os.path.basename(path))
    except (TypeError, ValueError) as e:
        raise fail(f"invalid contents: {e}") from e



__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "HEADER_MEMBER", "DatasetFileError", "load", "save"]
