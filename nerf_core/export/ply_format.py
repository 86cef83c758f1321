"""The PLY format itself: a header's claims, each checked against the file, and the elements' rows.

A header is a list of claims: the format and its version, each element's row count, each property's
type, each list's count type. ``parse_header`` checks every one of them (a known keyword, a whole
non-negative count, known types, a list counted by an integer type, no name twice) and
``read_elements`` checks them against the body *before* it allocates for them: a binary body must hold
at least ``count x the smallest row`` bytes per element, an ASCII body at least as many rows as the
elements claim (and no more). Rows are then read and checked one claim at a time: a token that is not
a number, a row with too few or too many values, a negative list count, a file that ends inside an
element. Every refusal is a ``GeometryFileError`` of one line naming the file and the element, row or
header line; nothing else escapes (``nerf_core/tests/test_fuzz_ply.py``).

Binary rows are read with numpy in one piece where the layout allows (every list of a row the same
length as in the first row, as in a triangle mesh); otherwise row by row.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Union

import numpy as np

TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
         "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
         "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
MAX_HEADER_BYTES = 1 << 20  # a header is a few hundred bytes; past this the file is not a PLY header
MAX_LINE = 4096
TRAILING_OK = (b"", b"\n", b"\r\n")  # a newline some writers add after a binary body

# A row's value: one number (scalar) or a list's items.
Column = Union[np.ndarray, list]


class GeometryFileError(ValueError):
    """A geometry file that is not a point set or a mesh this reader understands (the message names it)."""


@dataclass(frozen=True)
class Property:
    """One property of an element: ``dtype`` the numpy type code of its value (of a list's items);
    ``count`` the type code of a list's count, None for a scalar."""

    name: str
    dtype: str
    count: Optional[str] = None


@dataclass
class Element:
    """An element the header declares: its name, the rows it claims, its properties in file order."""

    name: str
    count: int
    properties: list = field(default_factory=list)

    def min_row_bytes(self) -> int:
        """The fewest bytes one binary row can take (every list empty)."""
        return sum(np.dtype(p.count or p.dtype).itemsize for p in self.properties)


@dataclass
class Header:
    """``format``: one of FORMATS; ``elements`` in file order."""

    format: str
    elements: list


def parse_header(fh, where: str) -> Header:
    """Read and check the header from ``fh`` (a binary file at its start); ``fh`` is left at the body.

    Raises:
        GeometryFileError: not a PLY, no (or a second) format line, an unknown format, version, keyword
            or type, a count that is not a whole number >= 0, a property outside an element, a name
            declared twice, a header without ``end_header`` (the message names the header line).
    """
    first = fh.readline(MAX_LINE)
    if first.rstrip(b"\r\n") != b"ply":
        raise GeometryFileError(f"{where}: not a PLY file (it does not start with a 'ply' line)")
    fmt, elements, used = None, [], len(first)
    number = 1
    while True:
        line = fh.readline(MAX_LINE)
        number += 1
        used += len(line)
        if not line:
            raise GeometryFileError(f"{where}: the PLY header has no 'end_header' (the file ends at header line "
                                    f"{number})")
        if used > MAX_HEADER_BYTES or (len(line) == MAX_LINE and not line.endswith(b"\n")):
            raise GeometryFileError(f"{where}: PLY header line {number} is longer than a header's "
                                    f"(no 'end_header' within {MAX_HEADER_BYTES} bytes, or a line over {MAX_LINE})")
        text = line.decode("ascii", "replace")
        words = text.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue  # free text: any bytes
        if "\ufffd" in text:
            raise GeometryFileError(f"{where}: PLY header line {number} is not ASCII text")

        def bad(why: str) -> GeometryFileError:
            return GeometryFileError(f"{where}: PLY header line {number} ({text.strip()[:60]!r}): {why}")

        key = words[0]
        if key == "end_header":
            break
        if key == "format":
            if fmt is not None:
                raise bad("a second 'format' line")
            if len(words) != 3 or words[1] not in FORMATS:
                raise bad(f"expected 'format' and one of {', '.join(FORMATS)} and a version")
            if words[2] not in ("1.0", "1"):
                raise bad(f"PLY version {words[2]!r}; this reader reads version 1.0")
            fmt = words[1]
        elif key == "element":
            if len(words) != 3:
                raise bad("expected 'element NAME COUNT'")
            try:
                count = int(words[2])
            except ValueError:
                raise bad(f"element {words[1]!r}: its count {words[2]!r} is not a whole number") from None
            if count < 0:
                raise bad(f"element {words[1]!r} claims {count} rows; a count is a whole number >= 0")
            if any(e.name == words[1] for e in elements):
                raise bad(f"a second element named {words[1]!r}")
            elements.append(Element(words[1], count))
        elif key == "property":
            if not elements:
                raise bad("a property before any element")
            elements[-1].properties.append(_property(words, elements[-1], bad))
        else:
            raise bad(f"unknown keyword {key!r} (a header has format, element, property, comment, obj_info)")
    if fmt is None:
        raise GeometryFileError(f"{where}: the PLY header has no 'format' line")
    for e in elements:
        if e.count and not e.properties:
            raise GeometryFileError(f"{where}: element {e.name!r} claims {e.count} rows but declares no property")
    return Header(fmt, elements)


def _property(words: list, element: Element, bad) -> Property:
    """A ``property TYPE NAME`` or ``property list COUNT_TYPE ITEM_TYPE NAME`` line of ``element``."""
    if len(words) >= 2 and words[1] == "list":
        if len(words) != 5:
            raise bad("expected 'property list COUNT_TYPE ITEM_TYPE NAME'")
        count_t, item_t, name = words[2], words[3], words[4]
        for t in (count_t, item_t):
            if t not in TYPES:
                raise bad(f"property {name!r} of element {element.name!r}: unknown type {t!r}")
        if TYPES[count_t][0] == "f":
            raise bad(f"property {name!r} of element {element.name!r}: a list's count type must be an integer "
                      f"type, not {count_t!r}")
        prop = Property(name, TYPES[item_t], TYPES[count_t])
    else:
        if len(words) != 3:
            raise bad("expected 'property TYPE NAME'")
        if words[1] not in TYPES:
            raise bad(f"property {words[2]!r} of element {element.name!r}: unknown type {words[1]!r}")
        prop = Property(words[2], TYPES[words[1]])
    if any(p.name == prop.name for p in element.properties):
        raise bad(f"a second property named {prop.name!r} in element {element.name!r}")
    return prop


def read_elements(body: bytes, header: Header, where: str) -> dict:
    """Every element's rows from ``body`` (the bytes after the header): ``{element: {property: column}}``,
    a column a 1-D array for a scalar, a 2-D array (rows, k) or a list of 1-D arrays for a list.

    Raises:
        GeometryFileError: the body holds fewer (or more) rows or bytes than the header claims, or a row
            that is not what its properties say (the message names the element and the row).
    """
    if header.format == "ascii":
        return _read_ascii(body, header.elements, where)
    order = "<" if header.format == "binary_little_endian" else ">"
    need = 0
    for e in header.elements:  # the claims against the bytes, before anything is allocated for them
        need += e.count * e.min_row_bytes()
        if need > len(body):
            raise GeometryFileError(
                f"{where}: element {e.name!r} claims {e.count} rows of at least {e.min_row_bytes()} bytes, but the "
                f"file holds {len(body)} bytes after its header in all: it is truncated or its header is wrong")
    data, pos = {}, 0
    for e in header.elements:
        data[e.name], pos = _read_binary(body, pos, e, order, where)
    if body[pos:] not in TRAILING_OK:
        raise GeometryFileError(f"{where}: {len(body) - pos} bytes follow the last element "
                                f"{header.elements[-1].name if header.elements else ''!r}: the header's counts do "
                                "not match the file")
    return data


def _read_binary(body: bytes, pos: int, e: Element, order: str, where: str) -> tuple[dict, int]:
    """Element ``e``'s columns from ``body`` at ``pos``, and the position after it."""
    if not e.count:
        return {p.name: np.empty(0, order + p.dtype) for p in e.properties}, pos
    lists = [p for p in e.properties if p.count]
    # the lengths of the first row's lists: the one-piece layout, if every row shares them
    ks = _row(body, pos, e, order, where, 0)[1] if lists else {}
    fields = []
    for p in e.properties:
        if p.count:  # a name with spaces: never a PLY property's
            fields += [(p.name + " count", order + p.count), (p.name, order + p.dtype, (ks[p.name],))]
        else:
            fields.append((p.name, order + p.dtype))
    dt = np.dtype(fields)
    end = pos + dt.itemsize * e.count
    if end <= len(body):
        table = np.frombuffer(body, dt, e.count, pos)
        if not lists or all(np.all(table[p.name + " count"] == ks[p.name]) for p in lists):
            return {p.name: table[p.name] for p in e.properties}, end
    elif not lists:
        raise GeometryFileError(f"{where}: the file ends inside element {e.name!r} (at row "
                                f"{(len(body) - pos) // dt.itemsize + 1} of {e.count})")
    columns = {p.name: [] for p in e.properties}
    for r in range(e.count):  # lists of several lengths: row by row
        pos, _, values = _row(body, pos, e, order, where, r, keep=True)
        for name, v in values.items():
            columns[name].append(v)
    return {p.name: (columns[p.name] if p.count else np.asarray(columns[p.name])) for p in e.properties}, pos


def _row(body: bytes, pos: int, e: Element, order: str, where: str, r: int, keep: bool = False):
    """One binary row of ``e`` at ``pos``: (the position after it, {list: length}, {property: value})."""
    ks, values = {}, {}
    for p in e.properties:
        if p.count:
            cdt = np.dtype(order + p.count)
            if pos + cdt.itemsize > len(body):
                raise GeometryFileError(f"{where}: the file ends inside element {e.name!r} (at row {r + 1} of "
                                        f"{e.count})")
            k = int(np.frombuffer(body, cdt, 1, pos)[0])
            pos += cdt.itemsize
            if k < 0:
                raise GeometryFileError(f"{where}: element {e.name!r} row {r + 1}: list {p.name!r} has a negative "
                                        f"length {k}")
            ks[p.name] = k
        else:
            k = None
        idt = np.dtype(order + p.dtype)
        size = idt.itemsize * (1 if k is None else k)
        if pos + size > len(body):
            raise GeometryFileError(f"{where}: the file ends inside element {e.name!r} (at row {r + 1} of {e.count})")
        if keep:
            v = np.frombuffer(body, idt, 1 if k is None else k, pos)
            values[p.name] = v[0] if k is None else v
        pos += size
    return pos, ks, values


def _read_ascii(body: bytes, elements: list, where: str) -> dict:
    """The elements of an ASCII body: one row a line (blank lines are skipped)."""
    rows = [ln for ln in body.splitlines() if ln.strip()]
    claimed = sum(e.count for e in elements)
    if len(rows) != claimed:  # the claims against the rows, before anything is parsed
        claims = ", ".join(f"{e.name} {e.count}" for e in elements)
        if len(rows) < claimed:
            inside = next(e.name for i, e in enumerate(elements) if sum(x.count for x in elements[:i + 1]) > len(rows))
            raise GeometryFileError(f"{where}: the header claims {claimed} rows ({claims}), but the file has "
                                    f"{len(rows)}: it is shorter than its header says (it ends inside element "
                                    f"{inside!r})")
        raise GeometryFileError(f"{where}: the header claims {claimed} rows ({claims}), but the file has "
                                f"{len(rows)}: the header's counts do not match the file")
    data, start = {}, 0
    for e in elements:
        data[e.name] = _ascii_element(rows[start:start + e.count], e, where, start)
        start += e.count
    return data


def _ascii_element(rows: list, e: Element, where: str, first_line: int) -> dict:
    """Element ``e``'s columns from its ASCII rows (``first_line``: the body row where they start)."""
    if not any(p.count for p in e.properties):  # scalars only: one conversion for the whole table
        tokens = [r.split() for r in rows]
        for r, t in enumerate(tokens):
            if len(t) != len(e.properties):
                raise GeometryFileError(f"{where}: element {e.name!r} row {r + 1}: {len(t)} values, but the "
                                        f"element has {len(e.properties)} properties")
        try:
            table = np.asarray(tokens, dtype=np.bytes_).astype(np.float64).reshape(len(rows), len(e.properties))
        except ValueError:
            table = None
        if table is None or not _integral_where_needed(table, e):
            for r, t in enumerate(tokens):  # find the first bad token, to name it
                for p, tok in zip(e.properties, t):
                    _number(tok, p, e, r, where)
        return {p.name: table[:, i] for i, p in enumerate(e.properties)}
    columns = {p.name: [] for p in e.properties}
    for r, line in enumerate(rows):
        t, i = line.split(), 0
        for p in e.properties:
            if p.count:
                if i >= len(t):
                    raise _short(where, e, r, len(t))
                k = _number(t[i], Property(p.name + " length", p.count), e, r, where)
                if k < 0:
                    raise GeometryFileError(f"{where}: element {e.name!r} row {r + 1}: list {p.name!r} has a "
                                            f"negative length {int(k)}")
                k = int(k)
                if i + 1 + k > len(t):
                    raise _short(where, e, r, len(t))
                columns[p.name].append(np.asarray([_number(v, p, e, r, where) for v in t[i + 1:i + 1 + k]],
                                                  dtype=np.float64))
                i += 1 + k
            else:
                if i >= len(t):
                    raise _short(where, e, r, len(t))
                columns[p.name].append(_number(t[i], p, e, r, where))
                i += 1
        if i != len(t):
            raise GeometryFileError(f"{where}: element {e.name!r} row {r + 1}: {len(t) - i} values more than its "
                                    "properties take")
    return {p.name: (columns[p.name] if p.count else np.asarray(columns[p.name], dtype=np.float64))
            for p in e.properties}


def _short(where: str, e: Element, r: int, n: int) -> GeometryFileError:
    return GeometryFileError(f"{where}: element {e.name!r} row {r + 1}: only {n} values, fewer than its properties "
                             "take")


def _integral_where_needed(table: np.ndarray, e: Element) -> bool:
    """True when every integer-typed column of ``table`` holds whole numbers."""
    for i, p in enumerate(e.properties):
        if p.dtype[0] != "f":
            col = table[:, i]
            if not np.all(np.isfinite(col) & (col == np.round(col))):
                return False
    return True


def _number(token: bytes, p: Property, e: Element, r: int, where: str) -> float:
    """One ASCII value of property ``p``: a number, and a whole one for an integer type."""
    try:
        v = float(token)
    except ValueError:
        v = None
    if v is None or (p.dtype[0] != "f" and not (np.isfinite(v) and v == round(v))):
        kind = "a number" if p.dtype[0] == "f" else "a whole number"
        raise GeometryFileError(f"{where}: element {e.name!r} row {r + 1}: {p.name} is "
                                f"{token.decode('ascii', 'replace')[:20]!r}, not {kind}")
    return v
