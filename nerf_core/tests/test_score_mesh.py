"""``score-mesh``: precision, recall, F-score, Chamfer-L1 and normal consistency on hand-made cases
whose answers are known, and a truth file that is not a point set or a mesh."""
import json

import numpy as np
import pytest

from nerf_core.cli.main import main
from nerf_core.export.ply import Geometry, write_mesh_ply
from nerf_core.export.score import score



def _write_points(path, pts):
    """A PLY point set (float x y z), as a capture's points3d.ply without normals or colours."""
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n" \
             "property float x\nproperty float y\nproperty float z\nend_header\n"
    path.write_bytes(header.encode() + np.asarray(pts, dtype="<f4").tobytes())


def _clusters():
    """Truth: 100 points at A = (0,0,0) and 100 at B = (1,0,0) (diagonal 1, tau = 0.01 at 1 %).
    Prediction: A moved by 0.001 (within tau) and 100 points at C = (0,1,0), 1 from A: precision 1/2,
    recall 1/2, F 1/2, each mean distance (0.001 + 1) / 2."""
    a, b, c = np.zeros((100, 3)), np.tile([1.0, 0, 0], (100, 1)), np.tile([0, 1.0, 0], (100, 1))
    return np.concatenate([a + [0, 0, 0.001], c]), np.concatenate([a, b])


def test_two_clusters_have_the_known_scores():
    pred, truth = _clusters()
    s = score(Geometry(pred), Geometry(truth), tau_share=0.01)
    assert s["tau"] == pytest.approx(0.01)
    assert s["precision"] == pytest.approx(0.5) and s["recall"] == pytest.approx(0.5)
    assert s["fscore"] == pytest.approx(0.5)
    assert s["chamfer"] == pytest.approx(0.5005, abs=1e-6) and s["normal_consistency"] is None
    # at tau below the shift nothing matches
    assert score(Geometry(pred), Geometry(truth), tau_share=0.0005)["fscore"] == 0.0


def _square(z=0.0, tilt=0.0):
    v = np.array([[0, 0, z], [1, 0, z + tilt], [1, 1, z + tilt], [0, 1, z]], dtype=np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_identical_meshes_score_perfectly_and_a_tilted_one_loses_normal_consistency():
    v, f = _square()
    same = score(Geometry(v, faces=f), Geometry(v, faces=f), max_points=20000)
    assert same["fscore"] == 1.0 and same["normal_consistency"] == pytest.approx(1.0)
    assert same["chamfer"] < 0.01  # two independent samplings of one square
    vt, ft = _square(tilt=1.0)  # tilted by 45 degrees about the y axis: |cos| = 1/sqrt(2)
    tilted = score(Geometry(vt, faces=ft), Geometry(v, faces=f), max_points=20000)
    assert tilted["normal_consistency"] == pytest.approx(2 ** -0.5, abs=1e-6)


def test_cli_prints_the_scores_as_the_last_json_line(tmp_path, capsys):
    pred, truth = _clusters()
    _write_points(tmp_path / "pred.ply", pred)
    _write_points(tmp_path / "points3d.ply", truth)
    assert main(["score-mesh", str(tmp_path / "pred.ply"), "--truth", str(tmp_path / "points3d.ply"),
                 "--tau", "0.01", "--tau", "0.0005"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in ("precision", "recall", "fscore", "chamfer", "tau"):
        assert key in out
    assert out["fscore"] == pytest.approx(0.5) and [r["fscore"] for r in out["by_tau"]] == pytest.approx([0.5, 0.0])


@pytest.mark.parametrize("content", [b"", b"not a ply at all", b"ply\nformat ascii 1.0\nelement face 0\n"
                                     b"property list uchar int vertex_indices\nend_header\n"])
def test_a_truth_that_is_not_a_point_set_or_mesh_is_one_line(tmp_path, capsys, content):
    v, f = _square()
    write_mesh_ply(tmp_path / "mesh.ply", v, f, np.zeros((4, 3), np.uint8))
    (tmp_path / "truth.ply").write_bytes(content)
    assert main(["score-mesh", str(tmp_path / "mesh.ply"), "--truth", str(tmp_path / "truth.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "truth.ply" in err[0]
    assert main(["score-mesh", str(tmp_path / "mesh.ply"), "--truth", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err


@pytest.mark.parametrize("value, words", [("2e9", ("must lie in 1..10000000", "GB", "got 2e9")),
                                          ("2000000000", ("must lie in 1..10000000",)), ("0", ("must lie in",)),
                                          ("1.5", ("expected a whole number",))])
def test_max_points_is_bounded_by_memory_naming_the_flag(tmp_path, capsys, value, words):
    v, f = _square()
    write_mesh_ply(tmp_path / "mesh.ply", v, f, np.zeros((4, 3), np.uint8))
    with pytest.raises(SystemExit) as info:
        main(["score-mesh", str(tmp_path / "mesh.ply"), "--truth", str(tmp_path / "mesh.ply"), "--max-points", value])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--max-points" in err and all(w in err for w in words), err
    with pytest.raises(ValueError, match="max_points must be an integer in 1..10000000"):
        score(Geometry(v, faces=f), Geometry(v, faces=f), max_points=2_000_000_000)
    assert main(["score-mesh", str(tmp_path / "mesh.ply"), "--truth", str(tmp_path / "mesh.ply"),
                 "--max-points", "1e3"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["n_pred"] == 1000


@pytest.mark.parametrize("truth", [[[1.0, 2.0, 3.0]], [[1.0, 2.0, 3.0]] * 50])
def test_a_truth_spanning_no_bounding_box_is_refused_naming_the_file(tmp_path, capsys, truth):
    # tau is a share of the truth's diagonal: with none, every mesh would score 0, as if it were wrong.
    _write_points(tmp_path / "pred.ply", _clusters()[0])
    _write_points(tmp_path / "one.ply", truth)
    assert main(["score-mesh", str(tmp_path / "pred.ply"), "--truth", str(tmp_path / "one.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--truth {tmp_path / 'one.ply'}" in err[0] and "spans no bounding box" in err[0]
    with pytest.raises(ValueError, match="the truth: .*spans no bounding box"):
        score(Geometry(_clusters()[0]), Geometry(np.asarray(truth)))
    # a one-point prediction against a real truth is scored, not refused
    assert main(["score-mesh", str(tmp_path / "one.ply"), "--truth", str(tmp_path / "pred.ply")]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["n_pred"] == len(truth)


def test_a_truth_no_training_camera_sees_is_named(tmp_path, capsys):
    from nerf_core.tests.conftest import make_dataset

    ds = make_dataset(tmp_path / "ds", layouts=("synthetic",), depth=False)
    far = np.array([[100.0, 100, 100], [101, 100, 100], [100, 101, 100]])  # far behind every ring camera's view
    _write_points(tmp_path / "far.ply", far)
    assert main(["score-mesh", str(tmp_path / "far.ply"), "--truth", str(tmp_path / "far.ply"),
                 "--cameras", str(ds)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--truth {tmp_path / 'far.ply'}: no point of the truth" in err[0], err
