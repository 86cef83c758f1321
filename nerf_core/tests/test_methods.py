"""Every method overfits a tiny analytic scene; checkpoints of a grown grid reload; options are JSON-able.

The scene: a unit-radius-0.6 sphere at the origin whose colour is 0.5 + 0.5 * normal, seen on white by
six cameras at distance 3 (16 x 16 pixels each). Ground truth comes from ray-sphere intersection, so
the test needs no files and no bpy.
"""
import json
import math

import pytest
import torch

from nerf_core.methods.catalog import DEFAULT_METHOD
from nerf_core.methods.registry import available_methods, build_model, saved_options
from nerf_core.volume import sampling, volrend

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
R = 0.6


def _look_at(eye):
    fwd = torch.nn.functional.normalize(-eye, dim=0)  # camera looks along -Z = towards the origin
    up = torch.tensor([0.0, 0.0, 1.0])
    right = torch.nn.functional.normalize(torch.linalg.cross(fwd, up), dim=0)
    true_up = torch.linalg.cross(right, fwd)
    return torch.stack([right, true_up, -fwd], dim=1)  # columns: camera X, Y, Z in world


def sphere_scene(n_cams=6, size=16, stripes=0.0):
    """Rays (o, d, near, far) and ground truth rgb (n, 3) on white; ``stripes`` adds a high-frequency pattern."""
    f = size / (2 * math.tan(math.radians(20)))
    j, i = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    cam_d = torch.stack([(i + 0.5 - size / 2) / f, -(j + 0.5 - size / 2) / f, -torch.ones(size, size)], -1).reshape(
        -1, 3
    )
    cam_d = torch.nn.functional.normalize(cam_d, dim=-1)
    os_, ds = [], []
    for k in range(n_cams):
        a, el = 2 * math.pi * k / n_cams, 0.4 * math.sin(k)
        eye = 3.0 * torch.tensor([math.cos(a) * math.cos(el), math.sin(a) * math.cos(el), math.sin(el)])
        ds.append(cam_d @ _look_at(eye).T)
        os_.append(eye.expand(size * size, 3))
    o, d = torch.cat(os_), torch.cat(ds)
    b = (o * d).sum(-1)
    disc = b * b - (o * o).sum(-1) + R * R
    hit = disc > 0
    t = -b - disc.clamp_min(0).sqrt()
    n = torch.nn.functional.normalize(o + t[:, None] * d, dim=-1)
    col = 0.5 + 0.5 * n
    if stripes:
        col = col * (0.6 + 0.4 * torch.sin(stripes * math.pi * n[:, 2:3]))
    rgb = torch.where(hit[:, None], col, torch.ones_like(col))
    near, far, _ = sampling.ray_aabb_intersect(o, d, BOX)
    return o, d, near, far, rgb


def overfit(name, steps, batch, lr=None, stripes=0.0, scale=1.0, **options):
    """Train ``name`` on the sphere scene; ``scale`` multiplies the whole scene (cameras, box, near/far)."""
    torch.manual_seed(0)
    o, d, near, far, rgb = sphere_scene(stripes=stripes)
    o, near, far = o * scale, near * scale, far * scale
    model = build_model(name, BOX * scale, **options)
    lr = lr or model.default_lr
    opt = torch.optim.Adam(model.param_groups(lr), betas=(0.9, 0.99))
    for step in range(steps):
        if model.training_hook(step, step / steps):
            opt = torch.optim.Adam(model.param_groups(lr), betas=(0.9, 0.99))
        idx = torch.randint(0, o.shape[0], (batch,))
        out = model.render_rays(o[idx], d[idx], near[idx], far[idx], torch.ones(batch, 3), True)
        loss = (out["rgb"] - rgb[idx]).square().mean()
        if "rgb_coarse" in out:
            loss = loss + (out["rgb_coarse"] - rgb[idx]).square().mean()
        if "aux_loss" in out:
            loss = loss + out["aux_loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
    model.eval()
    with torch.no_grad():
        out = model.render_rays(o, d, near, far, torch.ones_like(rgb), False)
    psnr = -10 * math.log10((out["rgb"] - rgb).square().mean().item())
    return model, out, psnr


SMALL_NERF = dict(width=64, depth=3, skip=2, n_coarse=16, n_fine=16, pos_freqs=6, dir_freqs=2)
SMALL_GRID = dict(res_init=16, res_final=32, upsample_at=[0.25], density_rank=8, app_rank=8, mlp_width=32,
                  occ_res=16, min_stage_steps=20)


pytestmark = pytest.mark.usefixtures("one_thread")  # small batches (see conftest.one_thread)


def test_catalog_lists_the_methods_and_a_fast_default():
    assert {"nerf", "nerf-nope", "vmgrid"} <= set(available_methods())
    assert DEFAULT_METHOD == "vmgrid"
    with pytest.raises(ValueError, match="unknown options"):
        build_model("vmgrid", BOX, resolutoin=32)


def test_vmgrid_overfits_the_sphere_and_grows():
    model, out, psnr = overfit("vmgrid", 120, 384, **SMALL_GRID)
    print(f"vmgrid {psnr:.2f} dB")
    assert psnr > 24.0
    assert model.field.resolution == 32 and model.run_state()["resolution"] == 32
    assert model.occupancy.occupied_fraction < 0.9  # empty space is being skipped
    assert torch.all((out["acc"] >= 0) & (out["acc"] <= 1 + 1e-5))


def test_vmgrid_occupancy_dilation_after_formed_is_an_option():
    """By default the grid keeps a one-cell shell around density for the whole run (forming geometry
    may spread); with ``occ_dilate_formed=False`` only cells whose own density passes ``occ_alpha``
    stay once ``formed()``, so surfaces get no empty shell."""
    model, _, _ = overfit("vmgrid", 120, 384, **{**SMALL_GRID, "occ_dilate_formed": False})
    assert model.formed()
    occ = model.occupancy

    def holds_density():  # the update's own rule: above occ_alpha at one step, or the mean if lower
        thr = -math.log1p(-model.options["occ_alpha"]) / model.step_size()
        return occ.density_ema > min(thr, float(occ.density_ema.mean()))

    model.update_occupancy()
    assert torch.equal(occ.binary, holds_density()) and occ.binary.any()  # no dilation once formed
    model.opts.occ_dilate_formed = True
    model.update_occupancy()
    shell = occ.binary & ~holds_density()
    assert shell.sum() > 0.2 * occ.binary.sum()  # the default: a one-cell shell round the density


def test_vmgrid_density_l1_waits_for_geometry():
    """The L1 prior must not start before the occupancy grid prunes.

    Regression: with Adam, L1 alone moves every density factor towards zero at the full learning rate
    while the rendering gradient of the nearly transparent initial field is tiny; both factors of
    each plane*line product reach ~0, a saddle with zero gradient, and the run stays at its initial
    PSNR for its whole budget (seen with ``--size auto`` on a 100 px capture). At 10x the default L1
    weight the old code ended at 11 dB on this sphere; waiting for geometry it reaches ~33 dB.
    """
    model = build_model("vmgrid", BOX, **SMALL_GRID)
    o, d, near, far, _ = sphere_scene()
    out = model.render_rays(o[:64], d[:64], near[:64], far[:64], torch.ones(64, 3), True)
    assert "aux_loss" not in out  # nothing pruned yet: no sparsity prior
    model.occupancy.binary[: model.occupancy.resolution // 2] = False  # half the box found empty
    out = model.render_rays(o[:64], d[:64], near[:64], far[:64], torch.ones(64, 3), True)
    assert "aux_loss" in out

    model, _, psnr = overfit("vmgrid", 120, 384, **{**SMALL_GRID, "l1_weight": 2e-3})
    assert psnr > 24.0, f"{psnr:.1f} dB: the density factors collapsed"
    assert float(model.field.density_planes.detach().abs().mean()) > 0.02


def test_nerf_overfits_and_beats_nerf_nope_on_a_high_frequency_target():
    _, out, pe = overfit("nerf", 150, 128, lr=3e-3, stripes=12.0, **SMALL_NERF)
    _, _, nope = overfit("nerf-nope", 150, 128, lr=3e-3, stripes=12.0, **SMALL_NERF)
    print(f"nerf {pe:.2f} dB, nerf-nope {nope:.2f} dB")
    assert pe > 18.0
    assert nope > 12.0  # it does learn something (a blurry sphere)
    assert pe > nope + 1.0


def test_render_rays_interface_for_every_method():
    o, d, near, far, _ = sphere_scene(n_cams=1, size=4)
    for name in ("nerf", "nerf-nope", "vmgrid"):
        opts = SMALL_NERF if name.startswith("nerf") else SMALL_GRID
        model = build_model(name, BOX, **opts)
        json.dumps(model.options)  # the trainer stores options in checkpoints as JSON
        out = model.render_rays(o, d, near, far, torch.ones(16, 3), True)
        assert out["rgb"].shape == (16, 3) and out["depth"].shape == (16,) and out["acc"].shape == (16,)
        assert isinstance(out["n_samples"], int) and out["n_samples"] > 0
        if name.startswith("nerf"):
            assert "rgb_coarse" not in out and model.fine is None  # one network behind the occupancy grid
            hier = build_model(name, BOX, **SMALL_NERF, sampler="hierarchical")
            assert hier.occupancy is None
            out = hier.render_rays(o, d, near, far, torch.ones(16, 3), True)
            assert out["rgb"].shape == (16, 3) and out["rgb_coarse"].shape == (16, 3)
        names = {g.get("name") for g in model.param_groups(1e-3)}
        if name == "vmgrid":
            groups = {g["name"]: g["lr"] for g in model.param_groups(1e-3)}
            assert groups["grids"] > groups["networks"]  # grids and MLPs have their own rates
        assert names


def test_grown_vmgrid_checkpoint_reloads_through_build_model():
    from nerf_core.runs.weights import load_weights

    model = build_model("vmgrid", BOX, **SMALL_GRID)
    model.occupancy.binary[:2] = False
    assert model.training_hook(25, 25 / 30)  # past upsample_at and min_stage_steps: grows
    assert model.field.resolution == 32
    state, options = model.state_dict(), json.loads(json.dumps(model.options))
    rebuilt = build_model("vmgrid", BOX, **options)
    rebuilt.load_state_dict(state)
    # The one loader: run state, check, resize, load (what eval and --resume do).
    old = build_model("vmgrid", BOX, **options)
    load_weights(old, {"model": state, "method_state": model.run_state()})
    o, d, near, far, _ = sphere_scene(n_cams=1, size=4)
    outs = [m.render_rays(o, d, near, far, torch.ones(16, 3), False)["rgb"] for m in (model, rebuilt, old)]
    assert torch.allclose(outs[0], outs[1]) and torch.allclose(outs[0], outs[2])


def test_nerf_occupancy_grid_prunes_empty_space_and_rendering_skips_it():
    model, out, psnr = overfit("nerf", 150, 128, lr=3e-3, **SMALL_NERF)
    assert psnr > 20.0
    # The sphere fills ~11 % of the box: after training most cells are known to be empty...
    assert model.occupancy.occupied_fraction < 0.6
    # ...and rays only sample near it: the pruned grid's fine step costs fewer samples than the
    # unpruned warm-up step would over the whole box.
    o, d, near, far, _ = sphere_scene()
    pruned = out["n_samples"]
    model.occupancy.reset()
    with torch.no_grad():
        full = model.render_rays(o, d, near, far, torch.ones(o.shape[0], 3), False)["n_samples"]
    assert pruned < 0.5 * full * model.options["warmup_step_scale"]
    with pytest.raises(ValueError, match="sampler"):
        build_model("nerf", BOX, sampler="proposal")


def test_nerf_early_ray_termination_while_training_changes_only_invisible_samples():
    model, _, _ = overfit("nerf", 120, 128, lr=3e-3, **SMALL_NERF)
    with torch.no_grad():  # a denser field: rays become opaque inside the occupied cells
        model.coarse.sigma_head.bias += 4.0
    o, d, near, far, _ = sphere_scene(n_cams=2)
    bg = torch.ones(o.shape[0], 3)
    outs = {}
    for ert in (False, True):
        model.opts.train_ert = ert
        torch.manual_seed(1)  # the same jittered samples
        outs[ert] = model.render_rays(o, d, near, far, bg, True)
    # Samples behind T < 1e-4 carry less than 1e-4 of a ray's colour: dropping them changes nothing visible,
    # and on the opaque sphere there are such samples to drop.
    assert outs[True]["n_samples"] < outs[False]["n_samples"]
    assert torch.allclose(outs[True]["rgb"], outs[False]["rgb"], atol=2e-4)


def test_nerf_renders_with_early_termination_as_one_full_pass_would():
    """Rendering terminates rays front to back and colours only visible samples from the trunk's kept
    features; the picture equals one pass of the whole network over every sample, computed here by hand."""
    model, _, _ = overfit("nerf", 120, 128, lr=3e-3, **SMALL_NERF)
    with torch.no_grad():
        model.coarse.sigma_head.bias += 4.0  # opaque: rays end inside the occupied cells
    model.eval()
    o, d, near, far, _ = sphere_scene(n_cams=2)
    bg = torch.ones(o.shape[0], 3)
    with torch.no_grad():
        out = model.render_rays(o, d, near, far, bg, False)
        t0, t1, ridx = sampling.occupied_samples(o, d, near, far, model.step_size(), model.occupancy.query,
                                                 jitter=False, max_samples=4096, near_fn=model.occupancy.query_near,
                                                 near_reach=model.occupancy.near_reach())
        pts = o[ridx] + d[ridx] * (0.5 * (t0 + t1)).unsqueeze(-1)
        sigma, rgb = model.coarse(pts, d[ridx])
        weights, _, _ = volrend.render_weight_from_density_packed(t0, t1, sigma, ridx, o.shape[0])
        acc = volrend.accumulate_along_rays_packed(weights, ridx, o.shape[0])
        full = volrend.composite_background(
            volrend.accumulate_along_rays_packed(weights, ridx, o.shape[0], rgb), acc, bg
        )
    assert float(acc.mean()) > 0.3  # something to compare
    assert torch.allclose(out["rgb"], full, atol=2e-4)
    assert torch.allclose(out["acc"], acc, atol=2e-4)
    assert out["n_samples"] < 0.7 * t0.shape[0]  # the trunk ran on fewer samples than one full pass


def test_nerf_auto_early_termination_follows_what_it_would_drop():
    """"auto" (the default) terminates rays early while that drops most samples (an opaque field) and
    measures again only every ``ert_probe_every`` renders while it would not (a transparent one)."""
    model, _, _ = overfit("nerf", 120, 128, lr=3e-3, **SMALL_NERF)
    assert model.options["train_ert"] == "auto"
    o, d, near, far, _ = sphere_scene(n_cams=2)
    bg = torch.ones(o.shape[0], 3)

    def samples(ert):
        model.opts.train_ert = ert
        torch.manual_seed(1)  # the same jittered samples
        return model.render_rays(o, d, near, far, bg, True)["n_samples"]

    with torch.no_grad():
        model.coarse.sigma_head.bias += 4.0  # opaque: most samples lie behind a surface
    model._ert_keep, model._ert_wait = None, 0
    everything, kept = samples(False), samples(True)
    assert kept < 0.6 * everything
    assert [samples("auto") for _ in range(3)] == [kept] * 3
    with torch.no_grad():
        model.coarse.sigma_head.bias -= 40.0  # transparent: nothing to drop
    model._ert_keep, model._ert_wait = None, 0
    assert samples("auto") == everything  # it measured: nothing dropped...
    assert model._ert_keep > 0.99
    model.opts.ert_probe_every, model._ert_wait = 3, 3
    # ...so it stays off, and measures again every third training render.
    assert [model._use_ert() for _ in range(6)] == [False, False, True, False, False, True]
    model._ert_keep = 0.5  # a measurement that drops half the samples turns it on while that lasts
    assert all(model._use_ert() for _ in range(5))
    model.opts.train_ert = False
    assert not model._use_ert()
    with pytest.raises(ValueError, match="train_ert"):
        build_model("nerf", BOX, train_ert="sometimes")


@pytest.mark.parametrize("name", ["vmgrid", "nerf"])
def test_a_scaled_scene_renders_the_same(name):
    """Density is learnt per box unit (``scene_box.box_length_unit``): the same weights in a box 1000x
    smaller give the same colours and opacity, and depths 1000x shorter. Per scene unit, the old rule,
    the small box's rays crossed 1000x less density (vmgrid: near-transparent; nerf: its fog thinned)."""
    opts = SMALL_GRID if name == "vmgrid" else SMALL_NERF
    o, d, near, far, _ = sphere_scene(n_cams=2, size=8)
    outs = []
    for scale in (1.0, 1e-3):
        torch.manual_seed(0)
        model = build_model(name, BOX * scale, **opts)
        with torch.no_grad():
            if name == "vmgrid":  # a field with substance in it, not the near-empty initial one
                model.field.density_shift = 0.0
            model.eval()
            outs.append(model.render_rays(o * scale, d, near * scale, far * scale, torch.ones(o.shape[0], 3), False))
    big, small = outs
    assert float(big["acc"].mean()) > 0.3  # something to compare
    assert torch.allclose(small["rgb"], big["rgb"], atol=1e-4)
    assert torch.allclose(small["acc"], big["acc"], atol=1e-4)
    assert torch.allclose(small["depth"] * 1e3, big["depth"], rtol=1e-3, atol=1e-4)


def test_vmgrid_trains_a_millimetre_scene_as_a_metre_one():
    """A 1.2 mm sphere (a ring or a bead modelled in metres) trains as well as a 1.2 m one. Per scene
    unit the grid needed raw densities ~1000x larger, climbing by the learning rate a step: 120 steps
    left it at 21 dB here, against 34 dB for the metre sphere (34 dB for both now)."""
    _, _, psnr_m = overfit("vmgrid", 120, 384, **SMALL_GRID)
    _, _, psnr_mm = overfit("vmgrid", 120, 384, scale=1e-3, **SMALL_GRID)
    assert psnr_mm > 24.0 and abs(psnr_mm - psnr_m) < 1.0, (psnr_mm, psnr_m)


@pytest.mark.parametrize("name", ["vmgrid", "nerf"])
def test_checkpoints_from_before_the_density_unit_load_per_scene_unit(name, tmp_path):
    """A checkpoint written before ``density_unit`` existed holds no such option and was trained per
    scene unit: every loader rebuilds it that way (``saved_options``), not with today's "box"."""
    from nerf_core.runs.checkpoints import model_from_checkpoint

    box = BOX * 3.0  # a box whose unit is not 1, so the two rules differ
    opts = SMALL_GRID if name == "vmgrid" else SMALL_NERF
    torch.manual_seed(0)
    old = build_model(name, box, **opts, density_unit="scene")
    options = {k: v for k, v in old.options.items() if k != "density_unit"}
    ckpt = {"method": name, "options": options, "aabb": box.tolist(), "model": old.state_dict()}
    model = model_from_checkpoint(ckpt, torch.device("cpu"))
    assert model.options["density_unit"] == "scene"
    o, d, near, far, _ = sphere_scene(n_cams=1, size=4)
    o, near, far = o * 3.0, near * 3.0, far * 3.0
    with torch.no_grad():
        a = old.eval().render_rays(o, d, near, far, torch.ones(16, 3), False)
        b = model.render_rays(o, d, near, far, torch.ones(16, 3), False)
    assert torch.equal(a["rgb"], b["rgb"]) and torch.equal(a["acc"], b["acc"])
    with pytest.raises(ValueError, match="density_unit"):
        build_model(name, BOX, density_unit="mm")


def test_nerf_checkpoint_from_before_the_occupancy_sampler_loads_as_hierarchical():
    torch.manual_seed(0)
    old = build_model("nerf", BOX, **SMALL_NERF, sampler="hierarchical", density_activation="softplus",
                      density_unit="scene")
    state = old.state_dict()
    # the options such a checkpoint recorded: none of the occupancy sampler's, no density activation
    options = {k: v for k, v in old.options.items() if k in ("width", "depth", "skip", "pos_freqs", "dir_freqs",
                                                             "use_pe", "n_coarse", "n_fine", "grad_reach")}
    model = build_model("nerf", BOX, **saved_options("nerf", options))  # what load_run does with an old config
    model.load_state_dict(state)
    assert model.options["sampler"] == "hierarchical" and model.occupancy is None
    assert model.options["density_activation"] == "softplus"
    o, d, near, far, _ = sphere_scene(n_cams=1, size=4)
    with torch.no_grad():
        a = old.render_rays(o, d, near, far, torch.ones(16, 3), False)["rgb"]
        b = model.render_rays(o, d, near, far, torch.ones(16, 3), False)["rgb"]
    assert torch.equal(a, b)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_methods_run_on_cuda():
    o, d, near, far, _ = (t.cuda() for t in sphere_scene(n_cams=1, size=4))
    for name in ("nerf", "vmgrid"):
        model = build_model(name, BOX).cuda()
        model.training_hook(16, 16 / 100)
        out = model.render_rays(o, d, near, far, torch.ones(16, 3, device="cuda"), True)
        assert out["rgb"].is_cuda


def test_nerf_density_activations_hand_computed():
    from nerf_core.fields.mlp import NeRFMLP

    raw = torch.tensor([-20.0, 0.0, 1.0, 3.0, 40.0])
    exp_net = NeRFMLP(BOX, density_activation="exp")
    soft_net = NeRFMLP(BOX, density_activation="softplus")
    # both shifted by -1; exp clamped at +-15 so an outlier cannot overflow
    assert torch.allclose(
        exp_net._activate(raw), torch.tensor([math.exp(-15), math.exp(-1), 1.0, math.exp(2), math.exp(15)])
    )
    assert torch.allclose(soft_net._activate(raw), torch.log1p(torch.exp(raw - 1.0)))
    with pytest.raises(ValueError, match="density_activation"):
        NeRFMLP(BOX, density_activation="relu")
