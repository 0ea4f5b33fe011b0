"""The data of a glTF avatar: its container (a .glb/.vrm's chunks, or a .gltf's JSON), the files
its buffers and images name, which must stay inside the avatar's folder, and its accessors as arrays.

An avatar is often downloaded or shared, so its URIs are not trusted: a relative path inside the
folder (no ``..`` out of it, no absolute path, no scheme, no symbolic link leading out), naming a
regular file (never a device or a FIFO, which would read for ever or block), read no further than
the bytes asked for. A ``data:`` URI must be base64. Every refusal is one ``InputFileError`` line.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import os
import stat
import struct
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import numpy as np

from convodrive.backends.avatar.gltf_check import COMPONENTS, WIDTHS, check_document
from convodrive.plumbing.errors import InputFileError

MAX_IMAGE_BYTES = 1 << 28
"""A texture file is read no further than this (256 MB)."""


class GltfData:
    """A glTF document whose structure ``check_document`` proved, and its binary data on demand."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.doc, self.bin = read_container(path)
        check_document(self.doc, path)
        self._buffers: dict[int, bytes] = {}

    def fail(self, problem: str) -> InputFileError:
        return InputFileError(self.path, problem)

    def buffer(self, index: int) -> bytes:
        """Buffer ``index``, read no further than its views reach (``check_document`` bounded them)."""
        if index not in self._buffers:
            entry = self.doc["buffers"][index]
            views = [v for v in self.doc.get("bufferViews", []) if v["buffer"] == index]
            need = max((v.get("byteOffset", 0) + v["byteLength"] for v in views), default=0)
            if "uri" not in entry:
                if self.bin is None:
                    raise self.fail(f"buffer {index} has no uri and the file has no binary chunk")
                data = self.bin[:need]
            else:
                data = read_uri(self.path, entry["uri"], f"buffer {index}", need)
            if len(data) < need:
                raise self.fail(f"buffer {index} holds {len(data)} bytes but its views need {need}")
            self._buffers[index] = data
        return self._buffers[index]

    def view_bytes(self, index: int) -> tuple[bytes, int, int | None]:
        view = self.doc["bufferViews"][index]
        data = self.buffer(view["buffer"])
        start = view.get("byteOffset", 0)
        return data[start : start + view["byteLength"]], view["byteLength"], view.get("byteStride")

    def accessor(self, index: int) -> np.ndarray:
        """(count, width) float64 or int64 array of accessor ``index``, sparse and normalised
        values resolved."""
        try:
            acc = self.doc["accessors"][index]
            dtype = np.dtype(COMPONENTS[acc["componentType"]]).newbyteorder("<")
            width, count = WIDTHS[acc["type"]], acc["count"]
            if "bufferView" in acc:
                data, _, stride = self.view_bytes(acc["bufferView"])
                offset, item = acc.get("byteOffset", 0), dtype.itemsize * width
                stride = stride or item
                raw = np.frombuffer(data, np.uint8, count=(count - 1) * stride + item, offset=offset)
                rows = np.lib.stride_tricks.as_strided(raw, (count, item), (stride, 1))
                out = np.ascontiguousarray(rows).view(dtype).reshape(count, width)
            else:
                out = np.zeros((count, width), dtype)
            out = out.astype(np.float64 if dtype.kind == "f" or acc.get("normalized") else np.int64)
            if acc.get("normalized") and dtype.kind != "f":
                info = np.iinfo(dtype)
                out = np.maximum(out / info.max, -1.0)
            sparse = acc.get("sparse")
            if sparse:
                idx_type = np.dtype(COMPONENTS[sparse["indices"]["componentType"]]).newbyteorder("<")
                idx_data, _, _ = self.view_bytes(sparse["indices"]["bufferView"])
                rows_idx = np.frombuffer(idx_data, idx_type, sparse["count"], sparse["indices"].get("byteOffset", 0))
                val_data, _, _ = self.view_bytes(sparse["values"]["bufferView"])
                values = np.frombuffer(val_data, dtype, sparse["count"] * width, sparse["values"].get("byteOffset", 0))
                out = out.copy()
                out[rows_idx.astype(np.int64)] = values.reshape(-1, width)
            return out
        except InputFileError:
            raise
        except (KeyError, IndexError, ValueError, TypeError) as exc:
            raise self.fail(f"accessor {index} is malformed ({exc.__class__.__name__}: {exc})") from None

    def image(self, index: int) -> np.ndarray | None:
        from PIL import Image, UnidentifiedImageError

        try:
            entry = self.doc["images"][index]
            if "bufferView" in entry:
                data = self.view_bytes(entry["bufferView"])[0]
            else:
                data = read_uri(self.path, entry.get("uri"), f"image {index}", MAX_IMAGE_BYTES)
            return np.asarray(Image.open(io.BytesIO(data)).convert("RGBA"))
        except (OSError, ValueError, UnidentifiedImageError, Image.DecompressionBombError):
            return None  # a texture we cannot decode (KTX2): base colour only


def read_container(path: Path) -> tuple[dict[str, Any], bytes | None]:
    """The JSON document and the binary chunk of a .glb/.vrm, or the JSON of a .gltf."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputFileError(path, f"cannot read ({exc.strerror or exc})") from None
    blob = None
    if data[:4] == b"glTF":
        if len(data) < 20:
            raise InputFileError(path, "truncated glTF binary (shorter than its header)")
        _, version, length = struct.unpack_from("<4sII", data)
        if version != 2:
            raise InputFileError(path, f"glTF version {version} is not supported (expected 2.0)")
        if length > len(data):
            raise InputFileError(path, f"truncated glTF binary ({len(data)} of {length} bytes)")
        offset, text = 12, None
        while offset + 8 <= length:
            size, kind = struct.unpack_from("<I4s", data, offset)
            chunk = data[offset + 8 : offset + 8 + size]
            if kind == b"JSON":
                text = chunk
            elif kind == b"BIN\0" and blob is None:
                blob = bytes(chunk)
            offset += 8 + size
        if text is None:
            raise InputFileError(path, "glTF binary without a JSON chunk")
    else:
        text = data
    try:
        doc = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise InputFileError(path, "not a glTF 2.0 file (neither a glTF binary nor glTF JSON)") from None
    except RecursionError:
        raise InputFileError(path, "not a usable glTF 2.0 file (its JSON is nested too deep)") from None
    asset = doc.get("asset") if isinstance(doc, dict) else None
    if not isinstance(asset, dict) or not str(asset.get("version", "")).startswith("2"):
        raise InputFileError(path, "not a glTF 2.0 file (no asset.version 2.0)")
    return doc, blob


def read_uri(path: Path, uri: object, what: str, limit: int) -> bytes:
    """At most ``limit`` bytes of the data ``uri`` names, for ``what`` ("buffer 0") of the avatar
    at ``path``: a base64 ``data:`` URI, or a regular file inside the avatar's folder."""
    if not isinstance(uri, str):
        raise InputFileError(path, f"{what}: uri must be a string")
    if uri.startswith("data:"):
        head, comma, payload = uri.partition(",")
        if not comma or not head.endswith(";base64"):
            raise InputFileError(path, f"{what}: only base64 data: URIs are read")
        try:
            return base64.b64decode(payload, validate=True)[:limit]
        except (binascii.Error, ValueError):
            raise InputFileError(path, f"{what}: its data: URI is not valid base64") from None
    return _read_inside(path, unquote(uri), what, limit)


def _read_inside(path: Path, rel: str, what: str, limit: int) -> bytes:
    folder = path.parent.resolve()
    if ":" in rel.split("/", 1)[0] or rel.startswith(("/", "\\")) or "\\" in rel:
        raise InputFileError(path, f"{what}: uri {rel!r} is not a relative path inside the avatar's folder")
    target = (folder / rel).resolve()
    if not target.is_relative_to(folder):
        raise InputFileError(path, f"{what}: uri {rel!r} leads out of the avatar's folder")
    try:
        fd = os.open(target, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO must not block the open
    except OSError as exc:
        raise InputFileError(path, f"{what}: cannot read {rel!r} ({exc.strerror or exc})") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise InputFileError(path, f"{what}: {rel!r} is not a regular file")
        try:
            return fh.read(limit)
        except OSError as exc:
            raise InputFileError(path, f"{what}: cannot read {rel!r} ({exc.strerror or exc})") from None
