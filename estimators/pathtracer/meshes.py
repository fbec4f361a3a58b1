"""PLY and serialized triangle meshes, read as Mitsuba 3's ``ply`` and ``serialized``
shapes read them.

Formats ``ascii``, ``binary_little_endian`` and ``binary_big_endian`` (version 1.0), the
scalar types of the PLY standard and Mitsuba's aliases (``uint8`` ... ``float64``,
``half``). What a render uses:

- ``vertex``: ``x, y, z``; vertex normals ``nx, ny, nz`` when all three are present;
  texture coordinates ``texture_u, texture_v``, ``s, t`` or ``u, v`` (Mitsuba's names),
  taken as they are (a PLY's v is not flipped, unlike an OBJ's).
- ``face``: the list ``vertex_indices`` (or ``vertex_index``), triangles only: Mitsuba
  declares the list with a fixed count of 3 and refuses any other, so a polygon is
  refused here too (triangulate the mesh first).
- Other vertex and face properties (colours, custom attributes) and other elements are
  read past and ignored: they change no image unless a texture reads them, which the
  tracer does not support.

PLY files refused, with ``SceneError`` naming the file and what is wrong: a malformed
header, a truncated body, trailing content after the last element (Mitsuba refuses it
too), non-triangle faces, vertex indices out of range, an ASCII integer field written as a
float (``2.0``), non-finite positions or uv, positions,
normals or uv stored as integers (Mitsuba would read them normalised to [0, 1] through
an sRGB curve), a list property other than the face's indices, and two sets of uv names
in one file. The file's size is capped by the caller (``scene.MAX_ASSET_BYTES``).

A reader of our own rather than ``plyfile``: the rules above are Mitsuba's, not the PLY
standard's (which allows polygons and integer coordinates), so they would have to be
checked on top of any general reader; with fixed three-index faces every element is a
fixed-size record, which numpy's structured dtypes read in one call.

Mitsuba's ``serialized`` meshes (``read_serialized``): versions 3 and 4, any mesh of
a file by ``shape_index``, positions, normals and uv in single or double precision,
vertex colours read past; a file whose header, end-of-file dictionary or zlib stream is
broken, that ends early, or whose triangles refer to vertices it lacks is refused, as
are non-finite positions, normals or uv (Mitsuba holds them as NaN).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np

from .scene import SceneError
from .text_numbers import FLOAT32_OVERFLOW

__all__ = ["PlyMesh", "read_ply", "read_serialized", "serialized_mesh", "write_ply",
           "write_serialized"]

# PLY type names (standard and Mitsuba's aliases) -> numpy type codes
_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
          "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
          "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "long": "i8", "ulong": "u8", "half": "f2", "float16": "f2",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_UV_NAMES = (("texture_u", "texture_v"), ("s", "t"), ("u", "v"))   # Mitsuba's order
_INDEX_LISTS = ("vertex_indices", "vertex_index")


@dataclass
class PlyMesh:
    """Vertices (n, 3), triangles (m, 3) as vertex indices, and the optional per-vertex
    normals (n, 3) and texture coordinates (n, 2), all float64 / int64."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    uvs: np.ndarray | None


@dataclass
class _Element:
    name: str
    count: int
    props: list          # (name, type code, is_list, count type code)


def _header(data: bytes, path: str) -> tuple[str | None, list, int]:
    """(byte order or None for ascii, elements, offset of the body)."""
    def fail(msg):
        raise SceneError(f"{path}: not a PLY file Mitsuba reads: {msg}")

    lines, pos = [], 0
    while True:                         # header lines up to the one that says end_header
        nl = data.find(b"\n", pos)
        if nl < 0:
            fail("no end_header line")
        lines.append(data[pos:nl])
        pos = nl + 1
        if lines[-1].strip() == b"end_header":
            break
    try:
        lines = [line.decode("ascii") for line in lines[:-1]]
    except UnicodeDecodeError:
        fail("the header is not ASCII text")
    if lines[0].strip() != "ply":
        fail("the first line must be 'ply'")
    order = "missing"
    elements: list[_Element] = []
    for number, line in enumerate(lines[1:], 2):
        tokens = line.split()
        if not tokens or tokens[0] == "comment":
            continue
        where = f"header line {number} ({line.strip()!r})"
        if tokens[0] == "format":
            if order != "missing" or len(tokens) != 3 or tokens[1] not in _FORMATS:
                fail(f"{where}: expected one 'format <{'|'.join(_FORMATS)}> 1.0'")
            if tokens[2] != "1.0":
                fail(f"{where}: version {tokens[2]!r}; only 1.0 exists")
            order = _FORMATS[tokens[1]]
        elif tokens[0] == "element":
            if len(tokens) != 3 or not tokens[2].isdigit():
                fail(f"{where}: expected 'element <name> <count>'")
            elements.append(_Element(tokens[1], int(tokens[2]), []))
        elif tokens[0] == "property":
            if order == "missing" or not elements:
                fail(f"{where}: a property before 'format' or 'element'")
            if tokens[1:2] == ["list"]:
                if len(tokens) != 5:
                    fail(f"{where}: expected 'property list <count type> <type> <name>'")
                count_type, item_type, name = tokens[2:]
                is_list = True
            else:
                if len(tokens) != 3:
                    fail(f"{where}: expected 'property <type> <name>'")
                count_type, (item_type, name), is_list = None, tokens[1:], False
            for t in (count_type, item_type):
                if t is not None and t not in _TYPES:
                    fail(f"{where}: unknown type {t!r}; supported: {', '.join(_TYPES)}")
            if name in {p[0] for p in elements[-1].props}:
                fail(f"{where}: property {name!r} twice")
            elements[-1].props.append((name, _TYPES[item_type], is_list,
                                       count_type and _TYPES[count_type]))
        else:
            fail(f"{where}: unknown keyword {tokens[0]!r}")
    if order == "missing":
        fail("no 'format' line")
    return order, elements, pos


def _dtype(el: _Element, order: str) -> np.dtype:
    """One record of ``el``: a list property is its count and three items."""
    fields = []
    for name, code, is_list, count_code in el.props:
        if is_list:
            fields.append((f"{name}.count", order + count_code))
            fields += [(f"{name}.{k}", order + code) for k in range(3)]
        else:
            fields.append((name, order + code))
    return np.dtype(fields)


def _lists_are_triangles(el: _Element, records: np.ndarray, path: str):
    """Mitsuba declares every list with a fixed count of 3 and refuses other counts."""
    for name, _, is_list, _ in el.props:
        counts = records[f"{name}.count"] if is_list else None
        if counts is not None and np.any(counts != 3):
            k = int(np.argmax(counts != 3))
            raise SceneError(f"{path}: {el.name} {k} has {int(counts[k])} vertices; Mitsuba "
                             "reads triangles only (triangulate the mesh)")


def _read_binary(data, offset, elements, order, path):
    records = {}
    for el in elements:
        dt = _dtype(el, order)
        need = dt.itemsize * el.count
        full = min(el.count, (len(data) - offset) // max(dt.itemsize, 1))
        records[el.name] = np.frombuffer(data, dt, full, offset)
        _lists_are_triangles(el, records[el.name], path)
        if full < el.count:
            raise SceneError(f"{path}: truncated: element {el.name!r} needs {need} bytes "
                             f"({el.count} records of {dt.itemsize}), {len(data) - offset} "
                             "are left")
        offset += need
    if offset != len(data):
        raise SceneError(f"{path}: {len(data) - offset} bytes of trailing content after "
                         "the last element (Mitsuba refuses such a file)")
    return records


def _read_ascii(data, offset, elements, path):
    tokens = data[offset:].split()
    records = {}
    pos = 0
    for el in elements:
        dt = _dtype(el, "=")
        width = len(dt.names)
        full = min(el.count, (len(tokens) - pos) // max(width, 1))
        block = tokens[pos:pos + width * full]
        try:
            values = np.array(block, dtype=np.float64).reshape(full, width)
        except ValueError:
            bad = next(t for t in block if not _is_number(t))
            raise SceneError(f"{path}: element {el.name!r}: {bad[:40]!r} is not a number"
                             ) from None
        out = np.zeros(full, dt)
        for k, name in enumerate(dt.names):
            column = values[:, k]
            if dt[name].kind in "iu":
                # digits after an optional sign, as Mitsuba's stream reads an integer: a
                # "2.0" (numpy's savetxt writes "2.000e+00") it refuses was read as 2
                written = np.array(block[k::width], dtype="S")
                literal = np.char.isdigit(np.char.lstrip(written, b"+-"))
                if not literal.all():
                    j = int(np.argmax(~literal))
                    raise SceneError(f"{path}: element {el.name!r}, record {j}: {name} = "
                                     f"{written[j][:40]!r} is not an integer (the header "
                                     f"declares {dt[name]}; Mitsuba refuses it too)")
                info = np.iinfo(dt[name])
                wrong = ~((column == np.round(column)) & (column >= info.min)
                          & (column <= info.max))
                if wrong.any():
                    j = int(np.argmax(wrong))
                    raise SceneError(f"{path}: element {el.name!r}, record {j}: {name} = "
                                     f"{column[j]!r} is not a {dt[name]}")
            out[name] = column
        _lists_are_triangles(el, out, path)
        if full < el.count:
            raise SceneError(f"{path}: truncated: element {el.name!r} needs "
                             f"{width * el.count} numbers ({el.count} records of {width}), "
                             f"{len(tokens) - pos} are left")
        records[el.name] = out
        pos += width * el.count
    if pos != len(tokens):
        raise SceneError(f"{path}: {len(tokens) - pos} numbers of trailing content after "
                         "the last element (Mitsuba refuses such a file)")
    return records


def _is_number(token: bytes) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def read_ply(path: str, *, normals: bool = True) -> PlyMesh:
    """Read a PLY triangle mesh; ``SceneError`` naming the file and the problem.
    ``normals=False`` reads past ``nx, ny, nz`` (as Mitsuba does with ``face_normals``)."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise SceneError(f"cannot read {path} ({e.strerror})") from None
    order, elements, offset = _header(data, path)
    byname = {el.name: el for el in elements}
    for need in ("vertex", "face"):
        if need not in byname:
            raise SceneError(f"{path}: no {need!r} element")
    for el in elements:
        lists = [p[0] for p in el.props if p[2]]
        if lists and not (el.name == "face" and lists in ([n] for n in _INDEX_LISTS)):
            raise SceneError(f"{path}: element {el.name!r} has the list property "
                             f"{lists[-1]!r}; the only list Mitsuba reads is the face's "
                             f"{' or '.join(_INDEX_LISTS)}")
    if not any(p[2] for p in byname["face"].props):
        raise SceneError(f"{path}: the face element has no vertex_indices list")
    records = (_read_ascii(data, offset, elements, path) if order is None
               else _read_binary(data, offset, elements, order, path))
    return _mesh(records["vertex"], records["face"], path, normals)


def _floats(vertex, names, path):
    for n in names:
        if vertex.dtype[n].kind != "f":
            raise SceneError(f"{path}: vertex property {n!r} is {vertex.dtype[n]} (integer); "
                             "Mitsuba reads integer vertex data normalised to [0, 1] through "
                             "an sRGB curve: store float, double or half")
    return np.stack([vertex[n].astype(np.float64) for n in names], axis=1)


def _rows_finite_in_float32(a: np.ndarray) -> np.ndarray:
    """Per row of ``a``: whether every value is finite once rounded to float32 (NaN, inf
    and magnitudes from ``FLOAT32_OVERFLOW`` up are not)."""
    return (np.abs(a) < FLOAT32_OVERFLOW).all(1)


def _refuse_unstorable(rows, path, what: str, more: str = "") -> None:
    """Refuse the first vertex whose row of ``rows`` (positions, normals, uv) is not
    finite in single precision, as Mitsuba stores it, naming the file, the vertex and
    ``what``."""
    finite = _rows_finite_in_float32(rows)
    if not finite.all():
        raise SceneError(f"{path}: vertex {int(np.argmax(~finite))} has {what} in single "
                         f"precision, as Mitsuba stores it (NaN, or beyond "
                         f"±3.4028235e38{more})")


def _mesh(vertex, face, path, read_normals=True) -> PlyMesh:
    names = set(vertex.dtype.names)
    if not {"x", "y", "z"} <= names:
        raise SceneError(f"{path}: the vertex element needs properties x, y and z")
    verts = _floats(vertex, "xyz", path)
    # a double beyond float32's range too: Mitsuba stores single precision and refuses
    # it ("invalid vertex position data")
    _refuse_unstorable(verts, path, "a non-finite position")
    normals = (_floats(vertex, ("nx", "ny", "nz"), path)
               if read_normals and {"nx", "ny", "nz"} <= names else None)
    if normals is not None:
        # Mitsuba loads a double normal beyond float32's range as inf and renders its
        # triangles black (a NaN normal); ours normalised it in float64 and lit them
        _refuse_unstorable(normals, path, "a normal that is not finite",
                           "; Mitsuba renders its triangles black")
    uv_sets = [pair for pair in _UV_NAMES if set(pair) <= names]
    if len(uv_sets) > 1:
        raise SceneError(f"{path}: texture coordinates named both {uv_sets[0]} and "
                         f"{uv_sets[1]}; Mitsuba's choice between them is undefined: keep one")
    uvs = _floats(vertex, uv_sets[0], path) if uv_sets else None
    if uvs is not None:
        # Mitsuba holds such a uv as inf or NaN; it was refused only as the prepared
        # triangles' "geometry ... reaches 1e+39", naming neither file nor uv
        _refuse_unstorable(uvs, path, "texture coordinates that are not finite")
    key = next(n for n in _INDEX_LISTS if f"{n}.count" in face.dtype.names)
    faces = np.stack([face[f"{key}.{k}"].astype(np.int64) for k in range(3)], axis=1)
    if len(faces) == 0:
        raise SceneError(f"{path}: no faces")
    bad = (faces < 0) | (faces >= len(verts))
    if bad.any():
        k = int(np.argmax(bad.any(axis=1)))
        raise SceneError(f"{path}: face {k} refers to vertex {int(faces[k][bad[k]][0])}; "
                         f"the file has {len(verts)} vertices")
    return PlyMesh(verts, faces, normals, uvs)


def write_ply(path: str, vertices, faces, *, normals=None, uvs=None, uv_names=("u", "v"),
              fmt: str = "binary_little_endian", vertex_type: str = "float",
              index_type: str = "int", count_type: str = "uchar") -> None:
    """Write a triangle mesh as PLY (``fmt`` ascii, binary_little_endian or
    binary_big_endian; ``vertex_type`` float or double for positions, normals and uv).
    ASCII numbers are written with 17 significant digits: read back, they are the
    values written, rounded once to ``vertex_type``."""
    if fmt not in _FORMATS:
        raise ValueError(f"fmt={fmt!r}; one of {', '.join(_FORMATS)}")
    for name, t in (("vertex_type", vertex_type), ("index_type", index_type),
                    ("count_type", count_type)):
        if t not in _TYPES:
            raise ValueError(f"{name}={t!r}; one of {', '.join(_TYPES)}")
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    columns = [("x", v[:, 0]), ("y", v[:, 1]), ("z", v[:, 2])]
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        columns += [("nx", n[:, 0]), ("ny", n[:, 1]), ("nz", n[:, 2])]
    if uvs is not None:
        t = np.asarray(uvs, dtype=np.float64).reshape(-1, 2)
        columns += [(uv_names[0], t[:, 0]), (uv_names[1], t[:, 1])]
    header = [b"ply", f"format {fmt} 1.0".encode(), f"element vertex {len(v)}".encode()]
    header += [f"property {vertex_type} {name}".encode() for name, _ in columns]
    header += [f"element face {len(f)}".encode(),
               f"property list {count_type} {index_type} vertex_indices".encode(),
               b"end_header"]
    order = _FORMATS[fmt] or "="
    vertex = _dtype(_Element("vertex", len(v),
                             [(name, _TYPES[vertex_type], False, None) for name, _ in columns]),
                    order)
    face = _dtype(_Element("face", len(f), [("vertex_indices", _TYPES[index_type], True,
                                             _TYPES[count_type])]), order)
    vrec, frec = np.zeros(len(v), vertex), np.zeros(len(f), face)
    for name, values in columns:
        vrec[name] = values
    frec["vertex_indices.count"] = 3
    for k in range(3):
        frec[f"vertex_indices.{k}"] = f[:, k]
    with open(path, "wb") as out:
        out.write(b"\n".join(header) + b"\n")
        if fmt != "ascii":
            out.write(vrec.tobytes() + frec.tobytes())
            return
        for rec in (vrec, frec):
            for row in rec.tolist():
                out.write(" ".join(repr(x) if isinstance(x, float) else str(x)
                                   for x in row).encode() + b"\n")


# ------------------------------------------------------------------ Mitsuba's serialized
#: the format identifier and the versions Mitsuba 3.9.1 reads (3: uint32 offsets in the
#: end-of-file dictionary, 4: uint64 offsets and a name per mesh)
SERIALIZED_MAGIC = 0x041C
SERIALIZED_VERSIONS = (3, 4)
#: the flags word's bits that change the layout (0x0010, "face normals", and 0x1000,
#: single precision, are ignored by Mitsuba 3.9.1: single is what is not double)
_HAS_NORMALS, _HAS_UVS, _HAS_COLOURS, _DOUBLE = 0x0001, 0x0002, 0x0008, 0x2000
_SINGLE = 0x1000        # written by ``serialized_mesh``, as Mitsuba writes it
#: compressed bytes fed to zlib at a time (the inflated data grows only as it is read)
_INFLATE_CHUNK = 1 << 20


class _Inflated:
    """The zlib stream of one mesh, inflated as far as it is read; ``read`` refuses a
    stream that is corrupt, ends early or inflates beyond ``cap`` bytes."""

    def __init__(self, data: memoryview, fail, cap: int):
        self._data, self._fail, self._cap = data, fail, cap
        self._z, self._fed, self._buf, self._pos = zlib.decompressobj(), 0, bytearray(), 0

    def read(self, n: int, what: str) -> bytes:
        while len(self._buf) - self._pos < n:
            if self._z.eof or self._fed >= len(self._data):
                self._fail(f"truncated: its compressed data ends {len(self._buf)} bytes in, "
                           f"short of {what}")
            chunk = self._data[self._fed:self._fed + _INFLATE_CHUNK]
            self._fed += len(chunk)
            try:
                self._buf += self._z.decompress(chunk)
            except zlib.error as e:
                self._fail(f"its compressed data is corrupt (zlib: {e})")
            if len(self._buf) > self._cap:
                self._fail(f"its mesh inflates beyond {self._cap} bytes")
        out = bytes(self._buf[self._pos:self._pos + n])
        self._pos += n
        return out

    def name(self) -> None:
        """Read past a version 4 mesh's NUL-terminated name, a chunk at a time (a byte a
        call took 1.2 s for a 3 MB name; a read-only review)."""
        while True:
            end = self._buf.find(b"\0", self._pos)
            if end >= 0:
                self._pos = end + 1
                return
            self._pos = len(self._buf)
            if self.read(1, "the mesh's name (a NUL-terminated string)") == b"\0":
                return


def _serialized_offset(data: bytes, version: int, shape_index: int, fail) -> int:
    """Where mesh ``shape_index`` starts, from the end-of-file dictionary (as Mitsuba
    seeks it: mesh 0 starts the file, the dictionary is read for the others only)."""
    if shape_index == 0:
        return 0
    if len(data) < 8:
        fail(f"shape_index={shape_index}, but the file is too short to hold the "
             "end-of-file dictionary of its meshes")
    count = int(np.frombuffer(data, "<u4", 1, len(data) - 4)[0])
    if shape_index >= count:
        # Mitsuba reads one entry past the dictionary at shape_index == count
        fail(f"shape_index={shape_index}, but the file holds {count} mesh"
             f"{'' if count == 1 else 'es'} (indices 0 to {count - 1})")
    size = 8 if version == 4 else 4
    at = len(data) - 4 - size * (count - shape_index)
    if at < 0:
        fail(f"its end-of-file dictionary claims {count} meshes, more than the file holds")
    offset = int(np.frombuffer(data, f"<u{size}", 1, at)[0])
    if offset > len(data) - 4 or data[offset:offset + 4] != data[:4]:
        fail(f"the end-of-file dictionary puts mesh {shape_index} at byte {offset}, "
             "where the file's header (its format identifier and version) is not")
    return offset


def read_serialized(path: str, shape_index: int = 0, *, normals: bool = True,
                    cap: int = 1 << 30) -> PlyMesh:
    """Mesh ``shape_index`` of a Mitsuba ``.serialized`` file (versions 3 and 4, single or
    double precision, with or without normals, uv and vertex colours, which are read
    past), as Mitsuba 3.9.1's ``serialized`` shape reads it; ``SceneError`` naming the
    file and the problem. ``normals=False`` reads past the normals (``face_normals``).
    ``cap``: the most bytes one mesh may inflate to."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise SceneError(f"cannot read {path} ({e.strerror})") from None

    def fail(msg):
        raise SceneError(f"{path}: not a serialized mesh Mitsuba reads: {msg}")

    if len(data) < 4:
        fail(f"{len(data)} bytes, shorter than its 4-byte header")
    magic, version = (int(x) for x in np.frombuffer(data, "<u2", 2))
    if magic != SERIALIZED_MAGIC:
        fail(f"it starts with 0x{magic:04X}, not the format identifier 0x041C")
    if version not in SERIALIZED_VERSIONS:
        fail(f"format version {version}; Mitsuba reads versions 3 and 4")
    if shape_index < 0:
        fail(f"shape_index={shape_index}; it must be >= 0")
    start = _serialized_offset(data, version, shape_index, fail) + 4
    where = f"mesh {shape_index}" if shape_index else "the mesh"

    def fail_mesh(msg):
        fail(f"{where}: {msg}")

    z = _Inflated(memoryview(data)[start:], fail_mesh, cap)
    flags = int(np.frombuffer(z.read(4, "the flags"), "<u4")[0])
    if version == 4:
        z.name()
    n_verts, n_faces = (int(x) for x in np.frombuffer(z.read(16, "the counts"), "<u8"))
    ftype = np.dtype("<f8" if flags & _DOUBLE else "<f4")
    widths = (3, 3 * bool(flags & _HAS_NORMALS), 2 * bool(flags & _HAS_UVS),
              3 * bool(flags & _HAS_COLOURS))
    size = n_verts * sum(widths) * ftype.itemsize + n_faces * 12
    if size > cap:
        fail_mesh(f"its {n_verts} vertices and {n_faces} triangles would take {size} "
                  f"bytes, beyond the {cap} bytes a mesh may take")

    def array(width, what):
        raw = z.read(n_verts * width * ftype.itemsize, what)
        return np.frombuffer(raw, ftype).reshape(n_verts, width).astype(np.float64)

    verts = array(3, f"its {n_verts} vertex positions")
    _refuse_unstorable(verts, path, "a non-finite position")
    vnormals = array(3, "its vertex normals") if widths[1] else None
    if not normals:
        vnormals = None
    elif vnormals is not None:
        _refuse_unstorable(vnormals, path, "a normal that is not finite",
                           "; Mitsuba renders its triangles black")
    uvs = array(2, "its texture coordinates") if widths[2] else None
    if uvs is not None:
        _refuse_unstorable(uvs, path, "texture coordinates that are not finite")
    if widths[3]:
        array(3, "its vertex colours")
    faces = np.frombuffer(z.read(n_faces * 12, f"its {n_faces} triangles"),
                          "<u4").reshape(n_faces, 3).astype(np.int64)
    if n_faces == 0:
        raise SceneError(f"{path}: {where} has no triangles")
    bad = faces >= n_verts
    if bad.any():
        k = int(np.argmax(bad.any(axis=1)))
        fail_mesh(f"triangle {k} refers to vertex {int(faces[k][bad[k]][0])}; the mesh "
                  f"has {n_verts} vertices")
    return PlyMesh(verts, faces, vnormals, uvs)


def serialized_mesh(vertices, faces, *, normals=None, uvs=None, colours=None,
                    double: bool = False, version: int = 4, name: str = "mesh",
                    flags: int = 0) -> bytes:
    """One mesh in Mitsuba's ``serialized`` format: the uncompressed identifier and
    version, then the zlib stream (level 9) of its flags (``flags`` added to those the
    arrays given set), its NUL-terminated name (version 4), its counts and arrays, and
    uint32 indices; several are concatenated by ``write_serialized``."""
    flags |= _DOUBLE if double else _SINGLE
    flags |= ((normals is not None) * _HAS_NORMALS | (uvs is not None) * _HAS_UVS
              | (colours is not None) * _HAS_COLOURS)
    ftype = "<f8" if double else "<f4"
    body = struct.pack("<I", flags) + (name.encode() + b"\0" if version == 4 else b"")
    body += struct.pack("<QQ", len(vertices), len(faces))
    body += b"".join(np.asarray(a, ftype).tobytes()
                     for a in (vertices, normals, uvs, colours) if a is not None)
    body += np.asarray(faces, "<u4").tobytes()
    return struct.pack("<HH", SERIALIZED_MAGIC, version) + zlib.compress(body, 9)


def write_serialized(path, meshes, version: int = 4) -> str:
    """Write ``serialized_mesh`` streams as one file with the end-of-file dictionary of
    their offsets (uint64 in version 4, uint32 in version 3) and their count."""
    offsets = np.cumsum([0] + [len(m) for m in meshes[:-1]])
    with open(path, "wb") as out:
        out.write(b"".join(meshes))
        out.write(np.asarray(offsets, "<u8" if version == 4 else "<u4").tobytes())
        out.write(struct.pack("<I", len(meshes)))
    return str(path)
