# SPDX-License-Identifier: Apache-2.0
"""VTK XML files for ParaView / VTK: tetrahedral meshes (.vtu) and time series (.pvd).

``write_vtu`` writes one UnstructuredGrid piece (VTK XML format version 1.0, little endian,
UInt64 block headers) with tetrahedra (VTK cell type 10) and point arrays, inline, as ASCII or as
base64 binary. ``write_pvd`` writes the collection that gives each file its simulation time.
``read_vtu`` reads such a file back strictly (what the writer writes, checked field by field).
"""
from __future__ import annotations

import base64
import os
import xml.etree.ElementTree as ET
from typing import Dict, Mapping, Optional, Sequence, Tuple

import numpy as np

VTK_TETRA = 10

_VTK_TYPES = {
    np.dtype(np.float32): "Float32", np.dtype(np.float64): "Float64",
    np.dtype(np.int32): "Int32", np.dtype(np.int64): "Int64",
    np.dtype(np.uint8): "UInt8", np.dtype(np.uint64): "UInt64",
}
_NP_TYPES = {v: k for k, v in _VTK_TYPES.items()}


def _data_array(parent: ET.Element, data: np.ndarray, name: Optional[str], components: int,
                binary: bool) -> None:
    data = np.ascontiguousarray(data)
    if data.dtype not in _VTK_TYPES:
        raise ValueError(f"array {name or '(points)'}: unsupported dtype {data.dtype}")
    attrs = {"type": _VTK_TYPES[data.dtype]}
    if name:
        attrs["Name"] = name
    if components != 1:
        attrs["NumberOfComponents"] = str(components)
    attrs["format"] = "binary" if binary else "ascii"
    el = ET.SubElement(parent, "DataArray", attrs)
    flat = data.reshape(-1).astype(data.dtype.newbyteorder("<"), copy=False)
    if binary:
        raw = flat.tobytes()
        header = np.array([len(raw)], dtype="<u8").tobytes()
        el.text = base64.b64encode(header + raw).decode("ascii")
    else:
        if data.dtype.kind == "f":
            el.text = " ".join(repr(float(x)) for x in flat)
        else:
            el.text = " ".join(str(int(x)) for x in flat)


def write_vtu(path: str, points: np.ndarray, tets: np.ndarray,
              point_data: Optional[Mapping[str, np.ndarray]] = None,
              binary: bool = True) -> None:
    """Writes points (N, 3) and tetrahedra (T, 4, indices into points) to ``path``.

    ``point_data``: name -> (N,) or (N, k) array. Float32/64, Int32/64 and UInt8 arrays are kept
    as they are.
    """
    points = np.asarray(points)
    tets = np.asarray(tets)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {points.shape}")
    if tets.ndim != 2 or tets.shape[1] != 4:
        raise ValueError(f"tets must be (T, 4), got {tets.shape}")
    if tets.size and (tets.min() < 0 or tets.max() >= len(points)):
        raise ValueError(f"tets index outside [0, {len(points)})")
    if points.dtype not in (np.float32, np.float64):
        points = points.astype(np.float64)
    root = ET.Element("VTKFile", {"type": "UnstructuredGrid", "version": "1.0",
                                  "byte_order": "LittleEndian", "header_type": "UInt64"})
    grid = ET.SubElement(root, "UnstructuredGrid")
    piece = ET.SubElement(grid, "Piece", {"NumberOfPoints": str(len(points)),
                                          "NumberOfCells": str(len(tets))})
    pd = ET.SubElement(piece, "PointData")
    for name, values in (point_data or {}).items():
        values = np.asarray(values)
        if values.shape[0] != len(points):
            raise ValueError(f"point_data {name!r} has {values.shape[0]} rows for {len(points)} points")
        comps = 1 if values.ndim == 1 else int(np.prod(values.shape[1:]))
        _data_array(pd, values, name, comps, binary)
    pts = ET.SubElement(piece, "Points")
    _data_array(pts, points, "Points", 3, binary)
    cells = ET.SubElement(piece, "Cells")
    _data_array(cells, tets.astype(np.int64).reshape(-1), "connectivity", 1, binary)
    _data_array(cells, np.arange(4, 4 * len(tets) + 1, 4, dtype=np.int64), "offsets", 1, binary)
    _data_array(cells, np.full(len(tets), VTK_TETRA, dtype=np.uint8), "types", 1, binary)
    tmp = path + ".tmp"
    ET.ElementTree(root).write(tmp, encoding="utf-8", xml_declaration=True)
    os.replace(tmp, path)


def write_pvd(path: str, entries: Sequence[Tuple[float, str]]) -> None:
    """A ParaView collection: (simulation time, file relative to ``path``'s folder) per step."""
    root = ET.Element("VTKFile", {"type": "Collection", "version": "0.1",
                                  "byte_order": "LittleEndian"})
    coll = ET.SubElement(root, "Collection")
    for t, f in entries:
        ET.SubElement(coll, "DataSet", {"timestep": repr(float(t)), "group": "", "part": "0",
                                        "file": f})
    tmp = path + ".tmp"
    ET.ElementTree(root).write(tmp, encoding="utf-8", xml_declaration=True)
    os.replace(tmp, path)


class VtuFormatError(ValueError):
    """A file that is not the VTU this module writes (the message says where)."""


def _read_array(el: ET.Element, count: int, where: str) -> np.ndarray:
    vtype = el.get("type")
    if vtype not in _NP_TYPES:
        raise VtuFormatError(f"{where}: DataArray type {vtype!r} unknown")
    dtype = _NP_TYPES[vtype].newbyteorder("<")
    comps = int(el.get("NumberOfComponents", "1"))
    fmt = el.get("format")
    text = (el.text or "").strip()
    if fmt == "binary":
        raw = base64.b64decode(text, validate=True)
        if len(raw) < 8:
            raise VtuFormatError(f"{where}: binary block shorter than its header")
        size = int(np.frombuffer(raw[:8], dtype="<u8")[0])
        if size != len(raw) - 8:
            raise VtuFormatError(f"{where}: header says {size} bytes, block holds {len(raw) - 8}")
        data = np.frombuffer(raw[8:], dtype=dtype)
    elif fmt == "ascii":
        data = np.array(text.split(), dtype=dtype) if text else np.zeros(0, dtype=dtype)
    else:
        raise VtuFormatError(f"{where}: format {fmt!r} is neither binary nor ascii")
    if data.size != count * comps:
        raise VtuFormatError(f"{where}: {data.size} values, expected {count} x {comps}")
    return data.reshape(count, comps) if comps != 1 else data


def read_vtu(path: str) -> Tuple[np.ndarray, np.ndarray, Dict[str, np.ndarray]]:
    """Reads a file ``write_vtu`` wrote: (points (N, 3), tets (T, 4), point data).

    Raises VtuFormatError when the structure is not a single-piece tetrahedral UnstructuredGrid
    with consistent counts, offsets and cell types.
    """
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise VtuFormatError(f"{path}: not well-formed XML: {e}") from None
    if root.tag != "VTKFile" or root.get("type") != "UnstructuredGrid":
        raise VtuFormatError(f"{path}: root is {root.tag} type={root.get('type')!r}, not a VTKFile UnstructuredGrid")
    if root.get("byte_order") != "LittleEndian" or root.get("header_type") != "UInt64":
        raise VtuFormatError(f"{path}: expected byte_order LittleEndian and header_type UInt64")
    pieces = root.findall("UnstructuredGrid/Piece")
    if len(pieces) != 1:
        raise VtuFormatError(f"{path}: {len(pieces)} pieces, expected 1")
    piece = pieces[0]
    n, t = int(piece.get("NumberOfPoints", "-1")), int(piece.get("NumberOfCells", "-1"))
    if n < 0 or t < 0:
        raise VtuFormatError(f"{path}: Piece lacks NumberOfPoints / NumberOfCells")
    pts_el = piece.findall("Points/DataArray")
    if len(pts_el) != 1 or pts_el[0].get("NumberOfComponents") != "3":
        raise VtuFormatError(f"{path}: Points needs one DataArray with 3 components")
    points = _read_array(pts_el[0], n, f"{path} Points")
    cells = {el.get("Name"): el for el in piece.findall("Cells/DataArray")}
    for name in ("connectivity", "offsets", "types"):
        if name not in cells:
            raise VtuFormatError(f"{path}: Cells lacks the {name} array")
    offsets = _read_array(cells["offsets"], t, f"{path} offsets")
    types = _read_array(cells["types"], t, f"{path} types")
    conn = _read_array(cells["connectivity"], 4 * t, f"{path} connectivity")
    if t and (not np.all(types == VTK_TETRA) or not np.array_equal(offsets, np.arange(4, 4 * t + 1, 4))):
        raise VtuFormatError(f"{path}: cells are not all tetrahedra with offsets 4, 8, ...")
    if conn.size and (conn.min() < 0 or conn.max() >= n):
        raise VtuFormatError(f"{path}: connectivity outside [0, {n})")
    data = {}
    for el in piece.findall("PointData/DataArray"):
        name = el.get("Name")
        if not name:
            raise VtuFormatError(f"{path}: a PointData array has no Name")
        data[name] = _read_array(el, n, f"{path} PointData {name}")
    return points, conn.reshape(t, 4), data


def read_pvd(path: str) -> list:
    """(time, file) entries of a collection, in file order."""
    root = ET.parse(path).getroot()
    if root.tag != "VTKFile" or root.get("type") != "Collection":
        raise VtuFormatError(f"{path}: not a VTKFile Collection")
    return [(float(d.get("timestep")), d.get("file")) for d in root.findall("Collection/DataSet")]
