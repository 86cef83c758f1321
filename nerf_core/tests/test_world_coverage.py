"""Which world directions the train views show, and the share of a held-out view that looks elsewhere."""
import json
import math

import numpy as np
import torch

from nerf_core.cameras.rays import Cameras
from nerf_core.fields.world_coverage import _dilate, covered_directions, unseen_world_share


def _camera(yaw_deg: float, pitch_deg: float = 0.0, w: int = 40, h: int = 40, fov_deg: float = 40.0,
            eye=(0.0, 0.0, 0.0)) -> Cameras:
    """A pinhole camera at ``eye`` looking along yaw (about +Z, from +X) and pitch (up from the horizon)."""
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    fwd = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)])
    z = -fwd
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
    f = 0.5 * w / math.tan(math.radians(fov_deg) / 2)
    return Cameras.create(c2w[None], f, f, w / 2, h / 2, w, h)


def _cat(*cams: Cameras) -> Cameras:
    return Cameras.create(
        torch.cat([c.c2w for c in cams]),
        torch.cat([c.fx for c in cams]),
        torch.cat([c.fy for c in cams]),
        torch.cat([c.cx for c in cams]),
        torch.cat([c.cy for c in cams]),
        torch.cat([c.width for c in cams]),
        torch.cat([c.height for c in cams]),
    )


def test_dilate_grows_one_cell_at_the_equator_and_more_towards_the_poles():
    n_v, n_u = 8, 16
    m = torch.zeros(n_v, n_u, dtype=torch.bool)
    m[4, 0] = True  # just below the equator (sin(theta) = 0.98: one cell each way)
    out = _dilate(m)
    want = torch.zeros_like(m)
    for r in (3, 4, 5):
        for c in (15, 0, 1):  # longitude wraps around
            want[r, c] = True
    assert torch.equal(out, want)

    # Row 0 (theta = 11.25 degrees): cells are sin(theta) = 0.195 as wide, so it grows ceil(5.1) = 6 cells.
    m = torch.zeros(n_v, n_u, dtype=torch.bool)
    m[0, 8] = True
    out = _dilate(m)
    assert out[0].nonzero().flatten().tolist() == list(range(2, 15))
    assert out[1].any() and not out[2].any()


def test_a_view_the_train_cameras_face_away_from_is_all_unseen():
    train = _camera(0.0)
    covered = covered_directions(train)
    assert unseen_world_share(_camera(180.0), 0, covered) == 1.0
    # The same direction from another place sees the same world: a direction, not a point.
    assert unseen_world_share(_camera(0.0, eye=(5.0, -3.0, 1.0)), 0, covered) == 0.0


def test_the_unseen_share_follows_the_overlap_of_the_views():
    train = _cat(_camera(0.0), _camera(120.0), _camera(240.0))  # 3 x 40 of 360 degrees seen
    covered = covered_directions(train)
    # Half a view turned past the first camera: the half that overlaps is seen. Cells are 2.1 degrees
    # (two train pixels) and seen cells grow by one, so up to ~4 of the other 20 degrees count as seen.
    share = unseen_world_share(_camera(20.0), 0, covered, stride=1)
    assert 0.38 < share < 0.5
    # Pitched up by half the field of view: the upper half is sky that no train camera saw.
    up = unseen_world_share(_camera(0.0, pitch_deg=20.0), 0, covered, stride=1)
    assert 0.38 < up < 0.5


def test_rays_through_the_scene_box_do_not_count():
    covered = covered_directions(_camera(0.0))
    away = _camera(180.0, eye=(3.0, 0.0, 0.0))  # looks back at the origin, at directions nobody saw
    assert unseen_world_share(away, 0, covered) == 1.0
    box = torch.tensor([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]])
    with_box = unseen_world_share(away, 0, covered, aabb=box, stride=1)
    # The box (half-size 0.5, 2.5 to 3.5 units ahead) fills the middle of the 40 degree view. Expected share:
    # an independent slab test of every pixel ray in numpy.
    f = 20 / math.tan(math.radians(20))
    j, i = np.mgrid[0:40, 0:40]
    d_cam = np.stack([(i + 0.5 - 20) / f, -(j + 0.5 - 20) / f, -np.ones(i.shape)], -1)
    d = d_cam @ away.c2w[0, :3, :3].double().numpy().T
    o = np.array([3.0, 0.0, 0.0])
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (-0.5 - o) / d, (0.5 - o) / d
    hit = np.minimum(t0, t1).max(-1) < np.maximum(t0, t1).min(-1)
    assert 0.2 < hit.mean() < 0.8
    assert abs(with_box - (1.0 - hit.mean())) < 1e-6


def _look_up_and_away(ds, frame: int) -> dict:
    """Turn test ``frame`` of a ring dataset to look outward and up: the sky it sees is in no train
    image. Returns the new test transforms."""
    meta = json.loads((ds / "transforms_test.json").read_text())
    c2w = np.array(meta["frames"][frame]["transform_matrix"])
    eye = c2w[:3, 3]
    fwd = eye / np.linalg.norm(eye) + np.array([0.0, 0.0, 1.5])  # outward and up
    z = -fwd / np.linalg.norm(fwd)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2] = x, np.cross(z, x), z
    meta["frames"][frame]["transform_matrix"] = c2w.tolist()
    (ds / "transforms_test.json").write_text(json.dumps(meta))
    return meta


def test_check_names_the_held_out_views_that_look_at_unseen_world(tmp_path, dataset_factory):
    from nerf_core.check.dataset import check_dataset
    from nerf_core.tests.test_environment import _make_opaque

    def world_warnings(root):
        return [w for w in check_dataset(root).warnings if "no train view shows" in w.message]

    ds = _make_opaque(dataset_factory(tmp_path / "ds", n_train=12, n_test=3, depth=False))
    # The ring's held-out cameras sit at other heights than the train ones, so some of them see a
    # little sky above what the train views show; test view 1 is not one of them.
    before = {(w.file, w.frame) for w in world_warnings(ds)}
    assert ("transforms_test.json", 1) not in before

    meta = _look_up_and_away(ds, 1)
    warns = [w for w in world_warnings(ds) if (w.file, w.frame) not in before]
    assert [(w.file, w.frame, w.frame_path) for w in warns] == [("transforms_test.json", 1, "./test/r_1")]
    assert int(warns[0].message.split(" %")[0]) >= 50  # it looks mostly at sky nobody photographed

    # A cut-out capture (transparent film) has no world to see: no warning.
    cut = dataset_factory(tmp_path / "cut", n_train=12, n_test=3, depth=False)
    (cut / "transforms_test.json").write_text(json.dumps(meta))
    assert not world_warnings(cut)


def test_eval_says_which_views_look_at_unseen_world(tmp_path, dataset_factory):
    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train
    from nerf_core.evaluation.evaluate import evaluate_run
    from nerf_core.tests.test_environment import _make_opaque

    ds = _make_opaque(dataset_factory(tmp_path / "ds", n_train=12, n_test=3, depth=False))
    _look_up_and_away(ds, 1)
    run = tmp_path / "run"
    train(TrainConfig(dataset=str(ds), out=str(run), method="test-grid", max_steps=2, batch_rays=64,
                      stdout_events=False, show_bar=False, eval_views=0))
    lines = []
    summary = evaluate_run(run, print_fn=lines.append, show_progress=False)
    assert "looks at world no train view shows" in lines[1] and lines[1].startswith("view   1 r_1")
    assert "no train view" not in lines[0]
    assert summary["unseen_world"]["r_1"] >= 0.5 and "r_0" not in summary["unseen_world"]


def test_large_views_are_traced_sparsely_without_leaving_gaps():
    from nerf_core.fields.world_coverage import TRAIN_RAYS_PER_VIEW, auto_stride

    big = _camera(0.0, w=1000, h=1000)
    assert auto_stride(big, TRAIN_RAYS_PER_VIEW) == 5  # 40 000 of the million pixels
    covered = covered_directions(big)
    # Every pixel of the same view, and of one turned by a fraction of a degree, lies in a seen cell.
    assert unseen_world_share(big, 0, covered, stride=1) == 0.0
    assert unseen_world_share(_camera(0.3, pitch_deg=0.2, w=1000, h=1000), 0, covered, stride=1) == 0.0
