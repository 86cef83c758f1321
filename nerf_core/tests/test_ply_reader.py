"""The PLY reader (``nerf_core/export/ply.py``, ``ply_format.py``): every claim of a header checked
against the file, before anything is allocated for it, each refusal one line naming the file and the
element, row or header line (issue 58, rules 2 and 6); and what other tools write, read."""
from __future__ import annotations

import numpy as np
import pytest

from nerf_core.cli.main import main
from nerf_core.export.ply import GeometryFileError, read_geometry, write_mesh_ply

TRI = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)


def _ascii(vertex_count="3", face_count="1", face_props="", body=b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
           count_type="uchar") -> bytes:
    return (f"ply\nformat ascii 1.0\ncomment made by hand\nobj_info a test\nelement vertex {vertex_count}\n"
            "property float x\nproperty float y\nproperty float z\n"
            f"element face {face_count}\nproperty list {count_type} int vertex_indices\n{face_props}"
            "end_header\n").encode() + body


def _refused(tmp_path, data: bytes, *words) -> str:
    path = tmp_path / "bad.ply"
    path.write_bytes(data)
    with pytest.raises(GeometryFileError) as info:
        read_geometry(path)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg, msg
    for w in words:
        assert w in msg, (w, msg)
    return msg


def test_a_well_formed_ascii_mesh_reads(tmp_path):
    (tmp_path / "ok.ply").write_bytes(_ascii())
    geo = read_geometry(tmp_path / "ok.ply")
    assert geo.points.tolist() == TRI.tolist() and geo.faces.tolist() == [[0, 1, 2]]


def test_a_header_claiming_four_billion_vertices_is_refused_before_allocating(tmp_path, monkeypatch):
    # Nothing may be allocated for the claim: numpy reads of the claimed size would take 60 GB.
    write_mesh_ply(tmp_path / "m.ply", TRI, [[0, 1, 2]], np.zeros((3, 3), np.uint8))
    raw = (tmp_path / "m.ply").read_bytes()
    big = raw.replace(b"element vertex 3", b"element vertex 4000000000")
    real_frombuffer = np.frombuffer
    monkeypatch.setattr(np, "frombuffer", lambda *a, **k: pytest.fail("read before the claim was checked"))
    _refused(tmp_path, big, "element 'vertex' claims 4000000000 rows", "bytes after its header")
    monkeypatch.setattr(np, "frombuffer", real_frombuffer)
    _refused(tmp_path, _ascii(vertex_count="4000000000"), "claims 4000000001 rows", "shorter than its header says")


@pytest.mark.parametrize("count, words", [("-3", ("claims -3 rows",)), ("4e9", ("'4e9' is not a whole number",)),
                                          ("three", ("'three' is not a whole number",))])
def test_a_count_that_is_not_a_whole_number_at_least_zero_names_the_header_line(tmp_path, count, words):
    _refused(tmp_path, _ascii(vertex_count=count), "header line 5", "element 'vertex'", *words)


def test_an_ascii_file_shorter_than_its_header_says_names_the_element(tmp_path):
    _refused(tmp_path, _ascii(vertex_count="4"), "claims 5 rows (vertex 4, face 1)", "has 4",
             "ends inside element 'face'")
    _refused(tmp_path, _ascii(vertex_count="2"), "the header's counts do not match the file")


@pytest.mark.parametrize("body, words", [
    (b"0 0 0\n1 0 0\n0 1 0\n3 0 x 2\n", ("element 'face' row 1", "'x', not a whole number")),
    (b"0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n", ("'1.5', not a whole number",)),
    (b"0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n", ("element 'vertex' row 2", "y is 'zero', not a number")),
    (b"0 0 0\n1 0\n0 1 0\n3 0 1 2\n", ("element 'vertex' row 2", "2 values")),
    (b"0 0 0\n1 0 0\n0 1 0\n3 0 1\n", ("element 'face' row 1", "fewer than its properties take")),
    (b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2 7\n", ("element 'face' row 1", "1 values more")),
    (b"0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n", ("a face names a vertex outside 0..2",)),
])
def test_a_bad_ascii_row_names_the_element_and_row(tmp_path, body, words):
    _refused(tmp_path, _ascii(body=body), *words)


def test_a_negative_list_count_is_named_in_ascii_and_binary(tmp_path):
    _refused(tmp_path, _ascii(body=b"0 0 0\n1 0 0\n0 1 0\n-3 0 1 2\n", count_type="char"),
             "element 'face' row 1", "negative length -3")
    header = (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
              b"property float z\nelement face 1\nproperty list char int vertex_indices\nend_header\n")
    _refused(tmp_path, header + TRI.astype("<f4").tobytes() + bytes([0xFD]) + np.arange(3, dtype="<i4").tobytes(),
             "element 'face' row 1", "negative length -3")


@pytest.mark.parametrize("line, words", [
    ("property float128 w", ("unknown type 'float128'",)),
    ("property list float int vertex_indices", ("count type must be an integer type",)),
    ("property list uchar quad vertex_indices", ("unknown type 'quad'",)),
    ("property float x", ("a second property named 'x'",)),
    ("element vertex 3", ("a second element named 'vertex'",)),
    ("format ascii 1.0", ("a second 'format' line",)),
    ("texture foo.png", ("unknown keyword 'texture'",)),
    ("property float", ("expected 'property TYPE NAME'",)),
])
def test_each_header_claim_is_checked_naming_its_line(tmp_path, line, words):
    header = _ascii().split(b"end_header\n")[0].replace(b"element face 1\n", f"{line}\nelement face 1\n".encode())
    _refused(tmp_path, header + b"end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "PLY header line 9", *words)


@pytest.mark.parametrize("data, words", [
    (b"ply\nformat binary_middle_endian 1.0\nend_header\n", ("header line 2", "binary_little_endian")),
    (b"ply\nformat ascii 2.0\nend_header\n", ("PLY version '2.0'",)),
    (b"ply\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n",
     ("no 'format' line",)),
    (b"ply\nproperty float x\n", ("a property before any element",)),
    (b"ply\nformat ascii 1.0\nelement vertex 1\n", ("no 'end_header'",)),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n\n", ("claims 1 rows but declares no property",)),
    (b"ply\nformat ascii 1.0\nelement v\xe9rtex 1\nend_header\n", ("header line 3 is not ASCII",)),
    (b"ply\n" + b"comment " + b"x" * 5000 + b"\n", ("longer than a header's",)),
    (b"PNG\x89\r\n", ("not a PLY file",)),
])
def test_a_header_that_is_not_a_ply_header_is_one_line(tmp_path, data, words):
    _refused(tmp_path, data, *words)


def _binary(order: str, vertex_type="float") -> bytes:
    fmt = {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    header = (f"ply\nformat {fmt} 1.0\nelement vertex 3\nproperty {vertex_type} x\nproperty {vertex_type} y\n"
              f"property {vertex_type} z\nelement face 2\nproperty list uchar uint vertex_indices\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n").encode()
    t = order + {"float": "f4", "double": "f8"}[vertex_type]
    tri = bytes([3]) + np.array([0, 1, 2], order + "u4").tobytes() + bytes([255, 0, 0])
    quad = bytes([4]) + np.array([0, 1, 2, 1], order + "u4").tobytes() + bytes([0, 255, 0])
    return header + TRI.astype(t).tobytes() + tri + quad


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("vertex_type", ["float", "double"])
def test_meshlab_face_colours_read_in_either_byte_order(tmp_path, order, vertex_type):
    # MeshLab's face-coloured PLY: red/green/blue after vertex_indices; polygons of several sizes.
    (tmp_path / "m.ply").write_bytes(_binary(order, vertex_type))
    geo = read_geometry(tmp_path / "m.ply")
    assert np.allclose(geo.points, TRI) and geo.faces.tolist() == [[0, 1, 2], [0, 1, 2], [0, 2, 1]]
    # ASCII, the same faces
    (tmp_path / "a.ply").write_bytes(_ascii(face_count="2", body=b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2 255 0 0\n"
                                            b"4 0 1 2 1 0 255 0\n",
                                            face_props="property uchar red\nproperty uchar green\n"
                                                       "property uchar blue\n"))
    assert read_geometry(tmp_path / "a.ply").faces.tolist() == geo.faces.tolist()


def test_a_truncated_binary_file_and_trailing_bytes_are_named(tmp_path):
    raw = _binary("<")
    _refused(tmp_path, raw[:-6], "the file ends inside element 'face' (at row 2 of 2)")
    _refused(tmp_path, raw[:-20], "the file ends inside element 'face'")
    _refused(tmp_path, raw + b"extra bytes", "11 bytes follow the last element 'face'")
    (tmp_path / "nl.ply").write_bytes(raw + b"\n")  # a newline some writers add: read
    assert len(read_geometry(tmp_path / "nl.ply").points) == 3


def test_the_cli_says_it_in_one_line(tmp_path, capsys):
    (tmp_path / "bad.ply").write_bytes(_ascii(body=b"0 0 0\n1 0 0\n0 1 0\n3 0 x 2\n"))
    write_mesh_ply(tmp_path / "m.ply", TRI, [[0, 1, 2]], np.zeros((3, 3), np.uint8))
    assert main(["score-mesh", str(tmp_path / "m.ply"), "--truth", str(tmp_path / "bad.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.ply: element 'face' row 1" in err[0] and "Traceback" not in err[0]
