"""Property-based tests (hypothesis) of the PLY reader (``nerf_core/export/ply.py``, ``ply_format.py``):
random headers, counts, property and list types, both byte orders and ASCII, then damaged (truncated,
bytes flipped, counts changed, junk appended). Every outcome is a correct read of what was written or
the reader's one-line ``GeometryFileError`` naming the file, never another exception (issue 58).

The profiles are test_fuzz.py's ("ci" by default; ``HYPOTHESIS_PROFILE=long`` for a longer hunt).
"""
from __future__ import annotations

import os
import re

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nerf_core.export.ply import GeometryFileError, read_geometry

settings.register_profile("ci", max_examples=60, deadline=None, derandomize=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
settings.register_profile("long", max_examples=3000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

FLOATS = ["float", "double", "float32", "float64"]
INTS = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4", "int8": "i1",
        "uint8": "u1", "int32": "i4", "uint32": "u4"}
FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
CODE = {"float": "f4", "double": "f8", "float32": "f4", "float64": "f8", **INTS}


@st.composite
def ply_file(draw):
    """(bytes of a well-formed PLY, its points (n, 3), its triangles (f, 3) or None)."""
    fmt = draw(st.sampled_from(sorted(FORMATS)))
    order = FORMATS[fmt] or "<"
    n = draw(st.integers(1, 6))
    extra = draw(st.lists(st.sampled_from(["nx", "ny", "nz", "red", "green", "blue", "alpha", "quality"]),
                          unique=True, max_size=4))
    names = draw(st.permutations(["x", "y", "z"] + extra))
    types = {p: draw(st.sampled_from(FLOATS)) if p in ("x", "y", "z") or p.startswith("n")
             else draw(st.sampled_from(["uchar", "float", "ushort"])) for p in names}
    values = {p: np.asarray(draw(st.lists(st.integers(-100, 100) if p in "xyz" else st.integers(0, 255),
                                          min_size=n, max_size=n)), dtype=np.float64) / (4 if p in "xyz" else 1)
              for p in names}
    polys = draw(st.lists(st.lists(st.integers(0, n - 1), min_size=3, max_size=5), max_size=4))
    count_t = draw(st.sampled_from(["uchar", "char", "ushort", "int", "uint"]))
    item_t = draw(st.sampled_from(["int", "uint", "short", "ushort", "uchar"]))
    face_extra = draw(st.lists(st.sampled_from(["red", "green", "blue", "flags"]), unique=True, max_size=3))
    comments = draw(st.lists(st.sampled_from(["comment made by a fuzzer", "obj_info nothing", "comment \xe9t\xe9", ""]),
                             max_size=2))
    head = ["ply", f"format {fmt} 1.0", *comments, f"element vertex {n}"]
    head += [f"property {types[p]} {p}" for p in names]
    with_faces = draw(st.booleans())
    if with_faces:
        head += [f"element face {len(polys)}", f"property list {count_t} {item_t} vertex_indices"]
        head += [f"property uchar {p}" for p in face_extra]
    head.append("end_header")
    body = b""
    if fmt == "ascii":
        rows = [" ".join(repr(float(values[p][i])) if types[p] in FLOATS else str(int(values[p][i])) for p in names)
                for i in range(n)]
        if with_faces:
            rows += [" ".join(map(str, [len(r), *r, *[7] * len(face_extra)])) for r in polys]
        body = ("\n".join(rows) + "\n").encode()
    else:
        for i in range(n):
            body += b"".join(np.asarray(values[p][i], order + CODE[types[p]]).tobytes() for p in names)
        if with_faces:
            for r in polys:
                body += np.asarray(len(r), order + CODE[count_t]).tobytes()
                body += np.asarray(r, order + CODE[item_t]).tobytes()
                body += bytes([7] * len(face_extra))
    tris = [(r[0], r[k], r[k + 1]) for r in polys for k in range(1, len(r) - 1)] if with_faces else []
    data = ("\n".join(head) + "\n").encode("latin-1") + body
    return data, np.stack([values["x"], values["y"], values["z"]], axis=1), tris


@st.composite
def damaged(draw, base):
    """``base`` (bytes) damaged one to three ways."""
    data = bytearray(base)
    for _ in range(draw(st.integers(1, 2))):
        how = draw(st.sampled_from(["value", "value", "value", "truncate", "flip", "insert", "append", "count",
                                    "token", "type"]))
        body = bytes(data).find(b"end_header\n") + len(b"end_header\n")
        # most damage goes into the body (the header's own is the other kinds' and the first byte's)
        low = body if body > 10 and body < len(data) and draw(st.integers(0, 3)) else 0
        if how == "truncate" and data:
            del data[draw(st.integers(low, len(data) - 1)):]
        elif how == "flip" and data:
            i = draw(st.integers(low, len(data) - 1))
            data[i] = draw(st.integers(0, 255))
        elif how == "insert":
            i = draw(st.integers(low, len(data)))
            data[i:i] = draw(st.binary(min_size=1, max_size=6))
        elif how == "append":
            data += draw(st.sampled_from([b"\n", b"junk", b"\x00\x00\x00\x00", b"1 2 3\n"]))
        elif how == "value":  # one number of the body (ASCII) replaced by a word that is not that number
            start = body
            spans = [m.span() for m in re.finditer(rb"-?[0-9.]+(e-?[0-9]+)?", bytes(data[start:]))]
            if start > 10 and spans:
                a, b = draw(st.sampled_from(spans))
                data[start + a:start + b] = draw(st.sampled_from([b"x", b"-3", b"1.5", b"nan", b"inf", b"1e999", b"",
                                                                  b"0x1f", b"9999999999", b"3 4", b"\xff"]))
        elif how in ("count", "token", "type"):
            text = bytes(data)
            old = draw(st.sampled_from({"count": [b"vertex ", b"face "], "token": [b"1.0", b"end_header", b"ply",
                                                                                  b" 0 ", b"format "],
                                        "type": [b"float", b"uchar", b"list ", b"int"]}[how]))
            new = draw(st.sampled_from([b"vertex 4000000000 ", b"vertex -3 ", b"face 1e9 ", b"x", b"", b"float128",
                                        b"list list ", b"double", b"-1", b"nan", b"\xff\xfe", b"\r\n"]))
            data = bytearray(text.replace(old, new, 1))
    return bytes(data)


def _read(tmp_path, data: bytes):
    path = tmp_path / "fuzz.ply"
    path.write_bytes(data)
    try:
        return read_geometry(path)
    except GeometryFileError as exc:
        msg = str(exc)
        assert "\n" not in msg and msg.startswith(str(path)), msg
        return None


def test_every_well_formed_ply_reads_back_what_was_written(tmp_path):
    @given(case=ply_file())
    def check(case):
        data, points, tris = case
        geo = _read(tmp_path, data)
        assert geo is not None, data[:400]
        assert np.allclose(geo.points, points)
        assert (geo.faces.tolist() if geo.faces is not None else []) == [list(t) for t in tris]

    check()


def test_every_damaged_ply_is_read_or_refused_in_one_line(tmp_path):
    @settings(max_examples=max(300, settings.default.max_examples))  # each is a few milliseconds
    @given(data=ply_file().flatmap(lambda case: damaged(case[0])))
    def check(data):
        geo = _read(tmp_path, data)
        if geo is not None:  # what was read is a geometry: finite points, faces naming them
            assert geo.points.ndim == 2 and geo.points.shape[1] == 3 and len(geo.points)
            assert np.isfinite(geo.points).all()
            if geo.faces is not None:
                assert geo.faces.min() >= 0 and geo.faces.max() < len(geo.points)

    check()


def test_random_bytes_after_a_ply_line_are_refused_in_one_line(tmp_path):
    @given(data=st.binary(max_size=200), fmt=st.sampled_from([b"", b"format ascii 1.0\n",
                                                              b"format binary_big_endian 1.0\n"]))
    def check(data, fmt):
        _read(tmp_path, b"ply\n" + fmt + data)

    check()
