"""FBX's node tree: binary FBX (any version) and ASCII FBX read into one tree, written back as binary FBX 7.4.

Blender's importer, which jiggle reads FBX through (rig.motion.fbx), reads binary FBX 7.1 and later only. ASCII
FBX holds the same tree as binary (a node: a name, a list of typed values, child nodes), so an ASCII file is read
here, its values given the types the binary form has, and written as binary for the importer. FBX 6.x files
(binary or ASCII) have another object model; rig.motion.fbx_legacy lifts their tree into 7.x's.

Value types are FBX's binary codes: Y int16, C bool/char, I int32, L int64, F float32, D float64, S string,
R bytes; f d l i b c arrays of float32, float64, int64, int32, bool, byte (NumPy arrays here). ASCII carries no
types, so they come from where a value sits, as the FBX SDK writes them and as Blender's importer checks them:
a `P:` property's values from its type name ("double", "Lcl Translation" -> D; "int", "enum", "bool" -> I;
"Short" -> Y; "KTime" -> L; strings -> S), object and connection ids L, an array (`*N { a: ... }`) from its
element (KeyTime int64, KeyValueFloat float32, index lists int32, others float64), other integers I and other
numbers D. ASCII
writes an object's name as "Class::Name", binary as "Name\\x00\\x01Class": every such string outside `P:` records
is stored in binary's form.

Errors: a file that is not FBX, is cut short or has a broken record raises InputError naming the file and the
byte (binary) or line (ASCII) where reading stopped.
"""
from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from jiggle.rig.base.errors import InputError

BINARY_MAGIC = b"Kaydara FBX Binary  \x00\x1a\x00"
WRITE_VERSION = 7400
_FOOTER_ID = b"\xfa\xbc\xab\x09\xd0\xc8\xd4\x66\xb1\x76\xfb\x83\x1c\xf7\x26\x7e"
_FOOTER_MAGIC = b"\xf8\x5a\x8c\x6a\xde\xf5\xd9\x7e\xec\xe9\x0c\xe3\x75\x8f\x29\x0b"
_SCALARS = {"Y": "<h", "C": "<B", "I": "<i", "F": "<f", "D": "<d", "L": "<q"}
_ARRAYS = {"f": np.float32, "d": np.float64, "l": np.int64, "i": np.int32, "b": np.uint8, "c": np.uint8}
CLASS_SEP = "\x00\x01"


@dataclass
class Node:
    """One FBX record: `name`, its values `props` (int, float, str, bytes or a NumPy array each) with their
    binary type codes `types` (one character per value), and its `children`."""
    name: str
    props: list = field(default_factory=list)
    types: str = ""
    children: list["Node"] = field(default_factory=list)

    def find(self, name: str) -> "Node | None":
        return next((c for c in self.children if c.name == name), None)

    def all(self, name: str) -> list["Node"]:
        return [c for c in self.children if c.name == name]


def file_version(nodes: list[Node]) -> int:
    """FBXHeaderExtension/FBXVersion of a tree (0 when absent)."""
    head = next((n for n in nodes if n.name == "FBXHeaderExtension"), None)
    v = head.find("FBXVersion") if head else None
    return int(v.props[0]) if v and v.props and isinstance(v.props[0], (int, np.integer)) else 0


def read_tree(path: str) -> tuple[list[Node], int, bool]:
    """(top-level nodes, FBX version, is_ascii) of a binary or ASCII FBX file."""
    with open(path, "rb") as fh:
        data = fh.read()
    if data.startswith(BINARY_MAGIC):
        nodes, version = _read_binary(data, path)
        return nodes, version, False
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    if not (text.lstrip().startswith(";") or "FBXHeaderExtension" in text[:4096]):
        raise InputError("not an FBX file (no 'Kaydara FBX Binary' header, and not FBX text)", path)
    nodes = _read_ascii(text, path)
    version = file_version(nodes)
    if not version:                             # the first comment line says it too: "; FBX 7.4.0 project file"
        m = re.match(r"\s*;\s*FBX (\d+)\.(\d+)", text)
        version = int(m.group(1)) * 1000 + int(m.group(2)) * 100 if m else 7000
    return nodes, version, True


_CHECKED = {"Geometry": ("Vertices",), "AnimationCurve": ("KeyValueFloat",),
            "Deformer": ("Weights", "Transform", "TransformLink")}


def check_finite(nodes: list[Node], path: str) -> None:
    """InputError when a mesh's vertices, a skin cluster's weights or matrices, or an animation curve's key values
    hold NaN or infinity (a damaged file; Blender's importer would carry them into the scene)."""
    objects = next((n for n in nodes if n.name == "Objects"), None)
    for o in (objects.children if objects else []):
        for field_name in _CHECKED.get(o.name, ()):
            f = o.find(field_name)
            if f is None or not f.props or not isinstance(f.props[0], np.ndarray) or f.props[0].dtype.kind != "f":
                continue
            bad = ~np.isfinite(f.props[0])
            if bad.any():
                cls, name = split_name(str(o.props[1])) if len(o.props) > 1 else (o.name, "")
                what = f"{o.name} {name!r}" if name else f"an {o.name} (id {o.props[0]})"
                raise InputError(f"{what}: {int(bad.sum())} of its {field_name} values are not numbers (NaN or "
                                 f"infinity): the file is damaged; export it again", path)


# ---------------------------------------------------------------------------------------------- binary

def _read_binary(data: bytes, path: str) -> tuple[list[Node], int]:
    if len(data) < 27:
        raise InputError("binary FBX cut short in its header", path)
    version = int.from_bytes(data[23:27], "little")
    wide = version >= 7500                      # 7.5 widened the record header's offsets to 64 bits
    head = struct.Struct("<QQQB" if wide else "<IIIB")
    nodes: list[Node] = []
    pos = 27
    try:
        while True:
            node, pos = _read_record(data, pos, head, path)
            if node is None:
                break
            nodes.append(node)
    except (struct.error, zlib.error, ValueError, IndexError) as e:
        raise InputError(f"binary FBX cut short or corrupt near byte {pos} ({e})", path) from None
    return nodes, version


def _read_record(data: bytes, pos: int, head: struct.Struct, path: str) -> tuple[Node | None, int]:
    end, nprops, _plen, nlen = head.unpack_from(data, pos)
    start = pos
    pos += head.size
    if end == 0:
        return None, pos
    if end > len(data) or end <= start:
        raise InputError(f"binary FBX record at byte {start} ends at byte {end}, outside the file "
                         f"({len(data)} bytes): the file is cut short or corrupt", path)
    name = data[pos:pos + nlen].decode("utf-8", "replace")
    pos += nlen
    props, types = [], []
    for _ in range(nprops):
        t = chr(data[pos])
        pos += 1
        if t in _SCALARS:
            fmt = struct.Struct(_SCALARS[t])
            props.append(fmt.unpack_from(data, pos)[0])
            pos += fmt.size
        elif t in "SR":
            n = struct.unpack_from("<I", data, pos)[0]
            raw = data[pos + 4:pos + 4 + n]
            if len(raw) != n:
                raise ValueError(f"a {n}-byte string runs past the end")
            props.append(raw.decode("utf-8", "surrogateescape") if t == "S" else bytes(raw))
            pos += 4 + n
        elif t in _ARRAYS:
            count, enc, clen = struct.unpack_from("<III", data, pos)
            raw = data[pos + 12:pos + 12 + clen]
            if len(raw) != clen:
                raise ValueError(f"an array of {clen} bytes runs past the end")
            pos += 12 + clen
            if enc == 1:
                raw = zlib.decompress(raw)
            elif enc != 0:
                raise ValueError(f"array encoding {enc} (0 or 1 expected)")
            dtype = np.dtype(_ARRAYS[t]).newbyteorder("<")
            if len(raw) != count * dtype.itemsize:
                raise ValueError(f"an array says {count} values but holds {len(raw) // dtype.itemsize}")
            props.append(np.frombuffer(raw, dtype).astype(_ARRAYS[t]))
        else:
            raise ValueError(f"unknown value type {t!r} in record {name!r} at byte {start}")
        types.append(t)
    node = Node(name, props, "".join(types))
    sentinel = head.size
    while pos < end - sentinel:
        child, pos = _read_record(data, pos, head, path)
        if child is None:
            break
        node.children.append(child)
    return node, end


def write_binary(nodes: list[Node], version: int = WRITE_VERSION) -> bytes:
    """The tree as a binary FBX file (7.4's 32-bit record offsets; arrays zlib-compressed)."""
    if version >= 7500:
        raise ValueError("only the 32-bit record layout (FBX 7.4 and before) is written")
    out = bytearray(BINARY_MAGIC + struct.pack("<I", version))
    for n in nodes:
        out += _encode(n, len(out))
    out += b"\x00" * 13
    out += _FOOTER_ID + b"\x00" * 4
    pad = (16 - len(out) % 16) or 16
    out += b"\x00" * pad + struct.pack("<I", version) + b"\x00" * 120 + _FOOTER_MAGIC
    return bytes(out)


def _encode(node: Node, offset: int) -> bytes:
    if len(node.props) != len(node.types):
        raise ValueError(f"record {node.name!r} has {len(node.props)} values and {len(node.types)} types")
    body = bytearray()
    for v, t in zip(node.props, node.types):
        body += t.encode()
        if t in _SCALARS:
            body += struct.pack(_SCALARS[t], v)
        elif t in "SR":
            raw = v.encode("utf-8", "surrogateescape") if isinstance(v, str) else bytes(v)
            body += struct.pack("<I", len(raw)) + raw
        else:
            arr = np.ascontiguousarray(v, dtype=np.dtype(_ARRAYS[t]).newbyteorder("<"))
            raw = arr.tobytes()
            packed = zlib.compress(raw, 1) if len(raw) > 128 else raw
            body += struct.pack("<III", arr.size, 1 if packed is not raw else 0, len(packed)) + packed
    name = node.name.encode("utf-8")
    start = offset + 13 + len(name) + len(body)
    kids = bytearray()
    for c in node.children:
        kids += _encode(c, start + len(kids))
    if node.children or not node.props:
        kids += b"\x00" * 13
    end = start + len(kids)
    return struct.pack("<IIIB", end, len(node.props), len(body), len(name)) + name + bytes(body) + bytes(kids)


# ----------------------------------------------------------------------------------------------- ASCII

class Bare(str):
    """An unquoted word among an ASCII record's values (`Shading: T`, the interpolation letters of FBX 6 keys)."""


_TOKEN = re.compile(r"""
    (?P<space>[ \t\r\n]+|;[^\n]*)
  | (?P<name>[A-Za-z_][A-Za-z0-9_|\-]*)[ \t]*:
  | "(?P<str>[^"]*)"
  | \*(?P<count>\d+)
  | (?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?:\#[A-Za-z]+\d*)?)
  | (?P<bare>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<punct>[,{}])
""", re.X)
_ARRAY_TEXT = re.compile(r"\s*a\s*:([^}]*)\}")


def _read_ascii(text: str, path: str) -> list[Node]:
    tokens = _tokens(text, path)
    nodes, _ = _ascii_nodes(tokens, 0, text, path, top=True)
    _type_tree(nodes)
    return nodes


def _line(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


def _tokens(text: str, path: str) -> list[tuple[str, object, int]]:
    out = []
    pos, n = 0, len(text)
    while pos < n:
        m = _TOKEN.match(text, pos)
        if m is None:
            raise InputError(f"ASCII FBX: unexpected text {text[pos:pos + 20]!r}", path,
                             field=f"line {_line(text, pos)}")
        kind = m.lastgroup
        if kind == "count":                     # `*N { a: v,v,... }`: parse the values in one go
            a = _ARRAY_TEXT.match(text, _skip_brace(text, m.end(), path))
            if a is None:
                raise InputError("ASCII FBX: an array `*N {` without its `a: ...}` values", path,
                                 field=f"line {_line(text, pos)}")
            vals = _numbers(a.group(1), text, a.start(1), path)
            if len(vals) != int(m.group("count")):
                raise InputError(f"ASCII FBX: an array says *{m.group('count')} values and holds {len(vals)}",
                                 path, field=f"line {_line(text, pos)}")
            out.append(("array", vals, pos))
            pos = a.end()
            continue
        if kind != "space":
            val = m.group(kind)
            if kind == "str":
                val = val.replace("&quot;", '"').replace("&lf;", "\n").replace("&cr;", "\r")
            elif kind == "num":
                val = _number(val)
            elif kind == "bare":
                val = Bare(val)
            out.append((kind, val, pos))
        pos = m.end()
    return out


def _skip_brace(text: str, pos: int, path: str) -> int:
    m = re.compile(r"\s*\{").match(text, pos)
    if m is None:
        raise InputError("ASCII FBX: `*N` not followed by `{`", path, field=f"line {_line(text, pos)}")
    return m.end()


def _number(s: str):
    if "#" in s:                                 # MSVC's 1.#INF / -1.#IND / 1.#QNAN
        if "IND" in s or "NAN" in s.upper():
            return float("nan")
        return float("-inf") if s.startswith("-") else float("inf")
    if re.fullmatch(r"[-+]?\d+", s):
        return int(s)
    return float(s)


def _numbers(body: str, text: str, at: int, path: str) -> np.ndarray:
    parts = [p for p in (q.strip() for q in body.split(",")) if p]
    try:
        if all(re.fullmatch(r"[-+]?\d+", p) for p in parts):
            return np.array([int(p) for p in parts], dtype=np.int64)
        return np.array([float(_number(p)) for p in parts], dtype=np.float64)
    except ValueError:
        raise InputError("ASCII FBX: an array holds something that is not a number", path,
                         field=f"line {_line(text, at)}") from None


def _ascii_nodes(tokens, i: int, text: str, path: str, top: bool) -> tuple[list[Node], int]:
    nodes = []
    n = len(tokens)
    while i < n:
        kind, val, at = tokens[i]
        if kind == "punct" and val == "}":
            if top:
                raise InputError("ASCII FBX: a `}` closes nothing", path, field=f"line {_line(text, at)}")
            return nodes, i + 1
        if kind != "name":
            raise InputError(f"ASCII FBX: expected a record name, found {val!r}", path, field=f"line {_line(text, at)}")
        node = Node(str(val))
        i += 1
        while i < n:                              # values, commas between them (a record may start with one)
            k, v, _ = tokens[i]
            if k in ("str", "num", "bare"):
                node.props.append(v)
            elif k == "array":
                node.props.append(v)
                node.types = "A"                  # marked; _type_tree gives the element type
            elif not (k == "punct" and v == ","):
                break
            i += 1
        if i < n and tokens[i][0] == "punct" and tokens[i][1] == "{":
            node.children, i = _ascii_nodes(tokens, i + 1, text, path, top=False)
        nodes.append(node)
    if not top:
        raise InputError("ASCII FBX: the file ends inside a record (a `{` is never closed)", path,
                         field=f"line {_line(text, len(text))}")
    return nodes, i


_KTIME_TYPES = {"KTime", "Time", "ULongLong"}
_INT_TYPES = {"int", "Integer", "enum", "Enum", "bool", "Bool", "Visibility Inheritance"}
_SHORT_TYPES = {"Short", "short", "UShort"}
_FLOAT_TYPES = {"Float", "float"}
_FLOAT32_ARRAYS = {"KeyValueFloat", "KeyAttrDataFloat"}
_INT64_ARRAYS = {"KeyTime"}
_INT_ARRAYS = {"PolygonVertexIndex", "Edges", "Materials", "Smoothing", "Indexes", "KeyAttrFlags", "KeyAttrRefCount",
               "PolygonGroup", "TextureId", "Visibility"}
_INT64_SCALARS = {"LocalTime", "ReferenceTime", "RootNode", "Node"}
_FLOAT_SCALARS = {"Default", "Link_DeformAcuracy"}


def _type_tree(nodes: list[Node], parent: str = "") -> None:
    """Give every value of an ASCII tree its binary type, in place (see the module's docstring)."""
    for node in nodes:
        if node.types == "A":
            node.props, node.types = _typed_array(node.name, node.props[0])
        elif node.name in ("P", "Property"):
            node.types = _property_types(node)
        else:
            node.types = "".join(_scalar_type(node, k, v, parent) for k, v in enumerate(node.props))
            node.props = [to_binary_name(v) if t == "S" else v for v, t in zip(node.props, node.types)]
        if node.name == "Content" and "S" in node.types:       # embedded media is base64 text in ASCII
            import base64
            node.props = [base64.b64decode(p) if t == "S" else p for p, t in zip(node.props, node.types)]
            node.types = node.types.replace("S", "R")
        node.props = [float(p) if t in "DF" else ord(p) if t == "C" else p for p, t in zip(node.props, node.types)]
        _type_tree(node.children, node.name)


def _typed_array(name: str, vals: np.ndarray) -> tuple[list, str]:
    if name in _FLOAT32_ARRAYS:
        return [vals.astype(np.float32)], "f"
    if vals.dtype.kind == "i" and (name in _INT_ARRAYS or name in _INT64_ARRAYS or name.endswith("Index")):
        if name in _INT64_ARRAYS or (vals.size and (vals.max() > 2**31 - 1 or vals.min() < -2**31)):
            return [vals.astype(np.int64)], "l"
        return [vals.astype(np.int32)], "i"
    return [vals.astype(np.float64)], "d"


def property_value_type(kind: str, v) -> str:
    """The binary type of one value of a property whose type name is `kind` (see the module docstring)."""
    if isinstance(v, str):
        return "S"
    if kind in _KTIME_TYPES:
        return "L"
    if kind in _INT_TYPES:
        return "I"
    if kind in _SHORT_TYPES:
        return "Y"
    return "F" if kind in _FLOAT_TYPES else "D"


def _property_types(node: Node) -> str:
    head = ["S"] * min(len(node.props), 4 if node.name == "P" else 3)
    kind = str(node.props[1]) if len(node.props) > 1 else ""
    return "".join(head) + "".join(property_value_type(kind, v) for v in node.props[len(head):])


def _scalar_type(node: Node, k: int, v, parent: str) -> str:
    if isinstance(v, Bare):
        return "C" if len(v) == 1 else "S"
    if isinstance(v, str):
        return "S"
    if isinstance(v, float):
        return "D"
    if node.name == "C" or (k == 0 and (parent == "Objects" or node.name == "Document")) \
            or node.name in _INT64_SCALARS:
        return "L"
    if node.name in _FLOAT_SCALARS:
        return "D"
    return "I" if -2**31 <= v < 2**31 else "L"


_CLASS_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]*::")


def to_binary_name(s: str) -> str:
    """"Class::Name" (ASCII) -> "Name\\x00\\x01Class" (binary); other strings unchanged."""
    if CLASS_SEP in s or not _CLASS_NAME.match(s):
        return s
    cls, name = s.split("::", 1)
    return name + CLASS_SEP + cls


def split_name(s: str) -> tuple[str, str]:
    """(class, name) of an object name in either form ("Model::Hips" or "Hips\\x00\\x01Model")."""
    if CLASS_SEP in s:
        name, cls = s.split(CLASS_SEP, 1)
        return cls, name
    if "::" in s:
        cls, name = s.split("::", 1)
        return cls, name
    return "", s
