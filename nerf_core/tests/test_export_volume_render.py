"""The exported volume renders as the NeRF does (issue 57 part 4): the density under the renderer's own
empty-space rule, the colour where the density is."""
import json
import pathlib
import re

import numpy as np
import torch

from nerf_core.cli.main import main
from nerf_core.contract import colour_management
from nerf_core.export import field, grid, volume
from nerf_core.methods.registry import build_model
from nerf_core.tests.test_export_mesh import SphereModel

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
EXPORT_DIR = pathlib.Path(__file__).resolve().parents[1] / "export"


def _half_skipped_vmgrid():
    """A vmgrid whose field has haze everywhere and whose occupancy grid is empty where x < 0."""
    torch.manual_seed(0)
    model = build_model("vmgrid", BOX, res_init=16)
    r = model.occupancy.resolution
    with torch.no_grad():
        model.occupancy.binary.fill_(True)
        model.occupancy.binary[: r // 2] = False
    return model


def test_exported_density_is_zero_where_the_renderer_skips():
    model = _half_skipped_vmgrid()
    pts = torch.rand(4000, 3) * 2 - 1
    raw = model.density_at(pts)
    assert float(raw[pts[:, 0] < -0.05].min()) > 0  # the field itself has density there: the rule must act
    sigma = field.density(model, pts)
    skipped = pts[:, 0] < 0
    assert torch.all(sigma[skipped] == 0)
    assert torch.equal(sigma[~skipped], raw[~skipped])
    arrays = volume.volume_grids(model, BOX.double().numpy(), 24)
    xs = grid.axes(BOX.double().numpy(), 24)[0]
    assert np.all(arrays["density"][xs < 0] == 0) and np.all(arrays["color"][xs < 0] == 0)
    assert np.all(arrays["density"][xs > 0] > 0)


def test_the_renderer_skips_what_sampled_at_says():
    """``sampled_at`` is the renderer's rule, not a copy of it: a ray that crosses only skipped cells
    renders transparent although the field has density along it, and one through occupied cells does not."""
    model = _half_skipped_vmgrid()
    model.eval()
    o = torch.tensor([[-0.5, -0.5, -3.0], [0.5, 0.5, -3.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    with torch.no_grad():
        near, far = model.ray_interval(o, d)
        out = model.render_rays(o, d, near, far, torch.ones(2, 3), training=False)
    assert float(out["acc"][0]) == 0.0 and float(out["acc"][1]) > 0.0
    assert not bool(model.sampled_at(torch.tensor([[-0.5, -0.5, 0.0]]))[0])
    assert bool(model.sampled_at(torch.tensor([[0.5, 0.5, 0.0]]))[0])


def test_only_export_field_reads_the_models_density():
    """The mechanism: every exporter reads density through ``export.field.density`` (which applies the
    renderer's empty-space rule); a module calling ``.density_at(`` itself would export the skipped haze."""
    offenders = [p.name for p in EXPORT_DIR.glob("*.py")
                 if p.name != "field.py" and re.search(r"\.density_at\(", p.read_text(encoding="utf-8"))]
    assert offenders == []


def test_colour_reaches_one_node_past_the_opaque_nodes():
    """Trilinear interpolation between an opaque coloured node and a black one outside would fade the
    surface's colour to black where the density is still high: every neighbour of an opaque node is coloured."""
    from nerf_core.tests.test_export_mesh import SphereModel

    box = BOX.double().numpy()
    arrays = volume.volume_grids(SphereModel(), box, 24)
    threshold = -np.log1p(-volume.MIN_STEP_ALPHA) / float(grid.spacing(box, 24).mean())
    opaque = arrays["density"] > threshold
    coloured = arrays["color"].max(axis=-1) > 0
    near = opaque.copy()
    for a in range(3):  # the 3x3x3 neighbourhood; the sphere stays inside the box, so no wrap-around
        near = near | np.roll(near, 1, axis=a) | np.roll(near, -1, axis=a)
    assert (near & ~opaque).sum() > 100  # a shell of nodes that were black before
    assert np.array_equal(coloured, near)


def _capture(tmp_path, cm):
    ds = tmp_path / "dataset"
    (ds / "nerf_capture").mkdir(parents=True)
    manifest = {"format": "nerf_bridge.capture", "render": {"color_management": cm}}
    (ds / "nerf_capture" / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    return ds


AGX = {"display_device": "sRGB", "view_transform": "AgX", "look": "None", "exposure": 0.5, "gamma": 1.0,
       "sequencer_colorspace": "sRGB"}


def test_the_capture_manifest_gives_its_colour_management(tmp_path):
    ds = _capture(tmp_path, AGX)
    assert colour_management.recorded(str(ds)) == {k: AGX[k] for k in colour_management.STANDARD}
    assert colour_management.recorded(str(tmp_path / "nowhere")) is None
    for bad in ({"view_transform": 3}, {"gamma": 0}, {"exposure": float("nan")}, "AgX"):
        assert colour_management.recorded(str(_capture(tmp_path / str(len(str(bad))), bad))) is None


def test_the_volume_file_carries_the_captures_view_transform(monkeypatch, tmp_path, capsys):
    from nerf_core.tests.conftest import use_model
    from nerf_core.tests.test_export_mesh import SphereModel

    ds = _capture(tmp_path, AGX)
    use_model(monkeypatch, SphereModel(), config={"dataset": str(ds)})
    out = tmp_path / "v.npz"
    assert main(["export", "volume", str(tmp_path / "run"), "--out", str(out), "--resolution", "16"]) == 0
    assert json.loads(str(volume.read_volume(out)["color_management"]))["view_transform"] == "AgX"
    use_model(monkeypatch, SphereModel(), config={"dataset": str(tmp_path / "no capture")})
    out2 = tmp_path / "v2.npz"
    assert main(["export", "volume", str(tmp_path / "run"), "--out", str(out2), "--resolution", "16"]) == 0
    assert json.loads(str(volume.read_volume(out2)["color_management"])) == {}
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert any("records no colour management" in n for n in summary["notes"])


class _SmallSphere(SphereModel):
    def detail_resolution(self):
        return 12


def test_a_volume_defaults_to_twice_the_models_grid_and_a_mesh_to_its_own(monkeypatch, tmp_path, capsys):
    from nerf_core.tests.conftest import use_model

    use_model(monkeypatch, _SmallSphere())
    assert main(["export", "volume", str(tmp_path / "run"), "--out", str(tmp_path / "v.npz")]) == 0
    assert volume.read_volume(tmp_path / "v.npz")["density"].shape == (24, 24, 24)
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["resolution"] == 24
    assert main(["export", "mesh", str(tmp_path / "run"), "--out", str(tmp_path / "m.ply")]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["resolution"] == 12


def test_a_finer_default_that_does_not_fit_falls_back_to_the_models_grid_with_a_note(monkeypatch, tmp_path, capsys):
    from nerf_core.tests.conftest import use_model

    use_model(monkeypatch, _SmallSphere())
    # room for 12^3 and the working set, not for 24^3
    monkeypatch.setattr(grid, "available_memory", lambda: grid.CHUNK_BYTES + 12 ** 3 * volume.BYTES_PER_SAMPLE + 100)
    assert main(["export", "volume", str(tmp_path / "run"), "--out", str(tmp_path / "v.npz")]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["resolution"] == 12
    assert any("24^3 grid does not fit in memory" in n for n in summary["notes"])
