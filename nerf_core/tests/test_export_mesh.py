"""Mesh export (``nerf_core.export``): a sphere of known radius comes back within one voxel, the
culling and floater rules, decimation, the PLY layout, and each bad input's one-line error."""
import json
import math
import os

import numpy as np
import pytest
import torch

from nerf_core.cameras.rays import Cameras
from nerf_core.cli.main import main
from nerf_core.export import grid, mesh
from nerf_core.export.ply import read_geometry, write_mesh_ply
from nerf_core.methods.base import RadianceModel
from nerf_core.tests.conftest import use_model

RADIUS = 0.6


class SphereNet(torch.nn.Module):
    """An analytic field: density rising from 0 to ``peak`` over ``width`` across a sphere's surface,
    colour red above z = 0 and blue below (so that colours can be checked)."""

    def __init__(self, radius=RADIUS, peak=1e4, width=1e-4, centre=(0.0, 0.0, 0.0), extra=()):
        super().__init__()
        self.radius, self.peak, self.width = radius, peak, width
        self.centres = [torch.tensor(centre)] + [torch.tensor(c) for c, _ in extra]
        self.radii = [radius] + [r for _, r in extra]

    def density(self, x):
        out = torch.zeros(x.shape[0])
        for c, r in zip(self.centres, self.radii):
            out = torch.maximum(out, self.peak * torch.sigmoid((r - (x - c).norm(dim=-1)) / self.width))
        return out

    def forward(self, x, d):
        rgb = torch.zeros(x.shape[0], 3)
        rgb[:, 0] = (x[:, 2] > 0).float()
        rgb[:, 2] = (x[:, 2] <= 0).float()
        return self.density(x), rgb


class SphereModel(RadianceModel):
    """A method whose field the export reads through the declared interface (``density_at``, ``colour_at``)."""

    method_name = "sphere"

    def __init__(self, **net):
        super().__init__(torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
        self.coarse = SphereNet(**net)

    def density_at(self, pts):
        return self.coarse.density(pts)

    def colour_at(self, pts, dirs):
        return self.coarse(pts, dirs)[1]


def ring_cameras(n=8, radius=3.0, w=40, h=40):
    """n cameras on a ring around the origin, looking at it."""
    c2w = []
    for k in range(n):
        a = 2 * math.pi * k / n
        eye = np.array([radius * math.cos(a), radius * math.sin(a), 0.5])
        fwd = -eye / np.linalg.norm(eye)
        right = np.cross(fwd, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, -fwd, eye
        c2w.append(m)
    f = 0.5 * w / math.tan(0.4)
    return Cameras.create(np.stack(c2w), [f] * n, [f] * n, [w / 2] * n, [h / 2] * n, [w] * n, [h] * n)


BOX = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def test_sphere_comes_back_within_one_voxel_with_outward_normals_and_its_colours():
    res = 48
    m = mesh.extract_mesh(SphereModel(), BOX, res, min_component=0.0)
    voxel = float(grid.spacing(BOX, res).mean())
    r = np.linalg.norm(m.vertices, axis=1)
    assert np.abs(r - RADIUS).max() < voxel
    assert abs(r.mean() - RADIUS) < 0.5 * voxel  # a step sampled on a grid biases outwards, never by a voxel
    radial = m.vertices / r[:, None]
    cos = np.sum(radial * m.normals, axis=1)
    assert cos.min() > 0.3 and cos.mean() > 0.9  # outward (a step field's mesh is a little terraced)
    up = m.vertices[:, 2] > 0.05
    down = m.vertices[:, 2] < -0.05
    assert (m.colors[up] == [255, 0, 0]).all() and (m.colors[down] == [0, 0, 255]).all()


def test_floaters_and_what_no_camera_sees_are_culled():
    # a far small sphere (a floater) and one outside every camera's view
    model = SphereModel(extra=[((0.8, 0.8, 0.8), 0.03)])
    cams = ring_cameras()
    keep_all = mesh.extract_mesh(model, BOX, 48, min_component=0.0)
    assert (np.linalg.norm(keep_all.vertices - 0.8, axis=1) < 0.1).any()
    culled = mesh.extract_mesh(model, BOX, 48, min_component=0.005, cameras=cams)
    assert not (np.linalg.norm(culled.vertices - 0.8, axis=1) < 0.1).any()
    assert culled.info["floaters_dropped"] == 1
    # a camera that sees only the upper half of the main sphere culls the lower half
    one = ring_cameras(n=1, radius=2.0)
    c2w = np.eye(4)
    c2w[:3, 3] = (0.0, 0.0, 2.0)  # above, looking down -Z: sees only the top
    top = Cameras.create(c2w[None], one.fx, one.fy, one.cx, one.cy, one.width, one.height)
    only_top = mesh.extract_mesh(model, BOX, 32, cameras=top)
    assert only_top.vertices[:, 2].min() > -0.1


def test_the_culling_projection_is_project_points():
    from nerf_core.cameras.rays import project_points

    cams = ring_cameras(n=5, w=40, h=30)
    pts = np.random.default_rng(0).uniform(-1.5, 1.5, (500, 3)).astype(np.float32)
    for v in range(len(cams)):
        u, row, depth = mesh._pixels_and_depth(cams, v, pts)
        uv, z = project_points(cams, v, torch.from_numpy(pts))
        front = z.numpy() > 0
        assert np.allclose(depth, z.numpy(), atol=1e-5)
        assert np.allclose(u[front], uv[front, 0].numpy(), atol=1e-3)
        assert np.allclose(row[front], uv[front, 1].numpy(), atol=1e-3)


def test_a_point_behind_a_wall_is_not_seen_and_one_in_front_is():
    """One camera at z = 3 looking down at a dense wall (z = 0, a 1x1 square of points): a point
    half a unit under the wall is hidden, one half a unit above it is seen, and so is the wall, but
    for the few points in the image cell of the one in front of it."""
    c2w = np.eye(4)
    c2w[:3, 3] = (0.0, 0.0, 3.0)
    one = ring_cameras(n=1, w=64, h=64)
    cam = Cameras.create(c2w[None], one.fx, one.fy, one.cx, one.cy, one.width, one.height)
    g = np.linspace(-0.5, 0.5, 101)
    wall = np.stack(np.meshgrid(g, g, indexing="ij") + [np.zeros((101, 101))], axis=-1).reshape(-1, 3)
    pts = np.concatenate([wall, [[0.1, 0.1, -0.5], [0.1, 0.1, 0.5], [3.0, 3.0, 0.0]]])
    seen = mesh.seen_by_cameras(pts, cam, voxel=0.01)
    hidden = np.flatnonzero(~seen[:-3])
    assert 0 < len(hidden) <= 25 and np.abs(wall[hidden, :2] - 0.1).max() < 0.06  # its 1 px cell: 0.04 units
    assert list(seen[-3:]) == [False, True, False]  # hidden, in front, outside the image
    assert mesh.seen_by_cameras(pts, cam)[-3:].tolist() == [True, True, False]  # the frustum alone


def test_decimation_reaches_about_the_asked_faces_and_keeps_the_shape():
    # a density that rises over a few voxels, as a trained field's does (a bare step's terraced mesh
    # stops the quadric decimation early)
    m = mesh.extract_mesh(SphereModel(width=0.02), BOX, 48, n_faces=500)
    assert 400 <= len(m.faces) <= 550
    r = np.linalg.norm(m.vertices, axis=1)
    assert r.std() < 0.01


def test_written_ply_is_the_conventional_layout_and_reads_back(tmp_path):
    m = mesh.extract_mesh(SphereModel(), BOX, 24)
    path = tmp_path / "m.ply"
    write_mesh_ply(path, m.vertices, m.faces, m.colors)
    head = path.read_bytes()[:400].decode("ascii", "replace")
    for line in ("format binary_little_endian 1.0", "property float x", "property uchar red",
                 "property list uchar int vertex_indices"):
        assert line in head
    geo = read_geometry(path)
    assert np.allclose(geo.points, m.vertices, atol=1e-6) and (geo.faces == m.faces).all()
    assert (geo.colors == m.colors).all()
    plyfile = pytest.importorskip("plyfile")
    data = plyfile.PlyData.read(str(path))
    assert data["vertex"].count == len(m.vertices) and data["face"].count == len(m.faces)


def test_no_surface_names_the_level_and_the_density_range():
    model = SphereModel(peak=0.1)  # a faint fog: never reaches the fixed level
    with pytest.raises(mesh.NoSurface, match=r"no surface at density level .* ranges over \[.*\]"):
        mesh.extract_mesh(model, BOX, 16)


def test_a_grid_too_large_says_how_much_memory_it_needs():
    with pytest.raises(ValueError, match=r"--resolution 100000: a 100000\^3 grid needs .* of memory"):
        grid.check_fits(100000, 16)


@pytest.fixture
def fake_run(monkeypatch, tmp_path):
    """``export`` on a run whose model is the analytic sphere (open_run replaced)."""
    use_model(monkeypatch, SphereModel())
    return tmp_path / "run"


def _last_json(capsys):
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_cli_writes_the_mesh_and_prints_a_summary(fake_run, tmp_path, capsys):
    out = tmp_path / "mesh.ply"
    assert main(["export", "mesh", str(fake_run), "--out", str(out), "--resolution", "32", "--faces", "300"]) == 0
    summary = _last_json(capsys)
    assert summary["faces"] == len(read_geometry(out).faces) and summary["resolution"] == 32
    assert summary["step"] == 7 and out.exists()
    # an existing file is kept without --overwrite
    before = out.read_bytes()
    assert main(["export", "mesh", str(fake_run), "--out", str(out), "--resolution", "16"]) == 2
    assert "exists; pass --overwrite" in capsys.readouterr().err and out.read_bytes() == before


@pytest.mark.parametrize("kind", ["folder", "fifo"])
def test_cli_refuses_an_output_that_is_not_a_file(fake_run, tmp_path, capsys, kind):
    out = tmp_path / "target"
    if kind == "folder":
        out.mkdir()
    else:
        os.mkfifo(out)
    assert main(["export", "mesh", str(fake_run), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("is a folder" in err[0] or "FIFO" in err[0])


def test_cli_no_surface_and_huge_grid_are_one_line_with_nothing_written(monkeypatch, tmp_path, capsys):
    use_model(monkeypatch, SphereModel(peak=0.1))
    out = tmp_path / "m.ply"
    assert main(["export", "mesh", "run", "--out", str(out), "--resolution", "16"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no surface at density level" in err[0] and not out.exists()
    assert main(["export", "volume", "run", "--out", str(tmp_path / "v.npz"), "--resolution", "100000"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs" in err[0] and "memory" in err[0]


def test_without_the_mesh_extra_the_error_names_it(monkeypatch, tmp_path, fake_run, capsys):
    from nerf_core.export import extra

    def missing(name):
        raise ImportError(f"No module named {name.split('.')[0]!r}")
    monkeypatch.setattr(extra.importlib, "import_module", missing)
    assert main(["export", "mesh", str(fake_run), "--out", str(tmp_path / "m.ply"), "--resolution", "16"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install nerf-bridge[mesh]" in err[0] and not (tmp_path / "m.ply").exists()


class RampNet(SphereNet):
    """A field as training leaves it: density rising linearly (``slope`` per scene unit of depth)
    into a sphere, or only within a shell of inner radius ``hollow``."""

    def __init__(self, slope=1000.0, hollow=0.0):
        super().__init__()
        self.slope, self.hollow = slope, hollow

    def density(self, x):
        r = x.norm(dim=-1)
        sigma = self.slope * (RADIUS - r).clamp_min(0)
        return torch.where(r < self.hollow, torch.zeros_like(sigma), sigma)


def test_the_level_is_where_training_rays_first_meet_the_surface():
    from nerf_core.export.level import CONTACT, rendered_surface_level

    model = SphereModel()
    model.coarse = RampNet()
    level = rendered_surface_level(model, ring_cameras(), BOX, n_rays=512)
    # Head-on, optical depth slope * x^2 / 2 reaches -ln(CONTACT) at sigma = sqrt(2 slope (-ln CONTACT));
    # oblique rays meet the ramp at a shallower angle and reach it at a lower density.
    head_on = math.sqrt(2 * 1000.0 * -math.log(CONTACT))
    assert 0.5 * head_on < level <= 1.02 * head_on
    m = mesh.extract_mesh(model, BOX, 48, cameras=ring_cameras())
    assert m.info["level_rule"] == "first contact of training rays" and m.info["level"] == pytest.approx(level, rel=0.1)


class HazyRampNet(RampNet):
    """The ramped sphere in a faint haze that fills the rest of the box (a field after a short training
    of a room seen from inside): the haze alone stops more than 5 % of the light before the sphere."""

    HAZE = 0.3

    def density(self, x):
        return torch.maximum(super().density(x), torch.full(x.shape[:1], self.HAZE))


def test_the_level_is_the_surface_not_the_haze_before_it():
    from nerf_core.export.level import CONTACT, rendered_surface_level

    model = SphereModel()
    model.coarse = HazyRampNet()
    # counted from the ray's start, the haze reaches 5 % opacity after -ln(0.95) / 0.3 = 0.17 units,
    # before most rays reach the sphere (the box's faces are 0.4 units from it)
    level = rendered_surface_level(model, ring_cameras(), BOX, n_rays=512)
    head_on = math.sqrt(2 * 1000.0 * -math.log(CONTACT))
    assert 0.5 * head_on < level <= 1.1 * head_on and level > 10 * HazyRampNet.HAZE
    m = mesh.extract_mesh(model, BOX, 48, cameras=ring_cameras())
    r = np.linalg.norm(m.vertices, axis=1)
    assert np.abs(r - RADIUS).max() < 2 * float(grid.spacing(BOX, 48).mean())  # on the sphere, no fog


def test_enclosed_empty_space_is_filled_so_a_shell_gives_its_outer_face_only():
    model = SphereModel()
    model.coarse = RampNet(hollow=0.4)
    both = mesh.extract_mesh(model, BOX, 48, level=20.0, fill_inside=False)
    outer = mesh.extract_mesh(model, BOX, 48, level=20.0)
    r_both, r_outer = (np.linalg.norm(m.vertices, axis=1) for m in (both, outer))
    assert (r_both < 0.45).any()  # the shell's inner face
    assert r_outer.min() > 0.5 and outer.info["enclosed_samples_filled"] > 0


def test_cli_writes_the_volume_file_of_the_contract(fake_run, tmp_path, capsys):
    from nerf_core.export.volume import read_volume

    out = tmp_path / "v.npz"
    assert main(["export", "volume", str(fake_run), "--out", str(out), "--resolution", "24"]) == 0
    summary = _last_json(capsys)
    v = read_volume(out)
    assert v["density"].shape == (24, 24, 24) and v["color"].dtype == np.uint8
    assert str(v["format"]) == "nerf_bridge.volume"
    idx = np.indices(v["density"].shape).reshape(3, -1).T
    pts = (v["box"][0] + idx * v["spacing"]).reshape(24, 24, 24, 3)
    r = np.linalg.norm(pts, axis=-1)
    inside = r < RADIUS - 0.1
    assert (v["density"][inside] > 1e3).all() and (v["density"][r > RADIUS + 0.1] < 1e-3).all()
    top, bottom = inside & (pts[..., 2] > 0.05), inside & (pts[..., 2] < -0.05)
    assert (v["color"][top] == [255, 0, 0]).all() and (v["color"][bottom] == [0, 0, 255]).all()
    # no colour where nothing is: the surface's nodes and their neighbours (one diagonal step, for
    # Cycles' interpolation) are coloured, nothing farther out
    assert not v["color"][r > RADIUS + 0.1 + float(np.linalg.norm(v["spacing"]))].any()
    assert summary["resolution"] == 24 and summary["density_range"][1] > 1e3


@pytest.mark.parametrize("kind,name", [("mesh", "m.txt"), ("mesh", "m.npz"), ("volume", "v.ply"), ("volume", "v")])
def test_an_output_name_with_the_wrong_suffix_is_one_line_with_nothing_written(tmp_path, fake_run, capsys, kind, name):
    out = tmp_path / name
    assert main(["export", kind, str(fake_run), "--out", str(out), "--resolution", "16"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    want = ".ply" if kind == "mesh" else ".npz"
    assert len(err) == 1 and f"name one ending in {want}" in err[0] and str(out) in err[0], err
    assert not out.exists()
