"""``view_dependent`` off (``nerf-noview``, ``vmgrid-noview``): colour is the same from every direction;
on (the default): it is not, and the default networks are built exactly as before the option."""
import pytest
import torch

from nerf_core.fields.encodings import direction_encoding
from nerf_core.methods.registry import available_methods, build_model

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _points_and_directions(m=64, k=5, seed=0):
    """(m, 3) points in the box, and k sets of (m, 3) unit directions (one random set per k)."""
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(m, 3, generator=g) * 1.6 - 0.8
    dirs = [torch.nn.functional.normalize(torch.randn(m, 3, generator=g), dim=-1) for _ in range(k)]
    return x, dirs


def _colour_fns(model):
    """Every path that turns (points, directions) into colour for this model: training and rendering."""
    if hasattr(model, "field"):  # vmgrid: the grad path and the no-grad lookup tables of rendering
        return [model.field.color, model.field.lookup().color]
    net = model.coarse  # nerf: the one network of the occupancy sampler, whole and from kept features
    return [lambda x, d: net(x, d)[1], lambda x, d: net.color_from_features(net.density_and_features(x)[1], d)]


def _randomise(model):
    """Give every weight (the colour MLP's zero-initialised last bias included) random values."""
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in model.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * 0.3)


def test_the_variants_are_registered():
    assert {"nerf-noview", "vmgrid-noview"} <= set(available_methods())


@pytest.mark.parametrize("name", ["vmgrid-noview", "nerf-noview"])
def test_noview_colour_does_not_depend_on_the_direction(name):
    model = build_model(name, BOX, **({"res_init": 16} if "vmgrid" in name else {"width": 32}))
    _randomise(model)
    assert model.options["view_dependent"] is False
    x, dirs = _points_and_directions()
    with torch.no_grad():
        for fn in _colour_fns(model):
            ref = fn(x, dirs[0])
            for d in dirs[1:]:
                assert torch.equal(fn(x, d), ref)  # bit for bit: the direction is not an input at all


def test_vmgrid_noview_colour_is_the_appearance_mlp_alone_by_hand():
    model = build_model("vmgrid-noview", BOX, res_init=16, app_dim=27)
    _randomise(model)
    f = model.field
    assert f.mlp[0].in_features == 27  # the appearance feature only: no direction columns
    x, dirs = _points_and_directions(m=8)
    with torch.no_grad():
        feat = f.basis(f.app_features(x))
        by_hand = torch.sigmoid(f.mlp(feat))
        torch.testing.assert_close(f.color(x, dirs[0]), by_hand, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", ["vmgrid", "nerf"])
def test_default_colour_depends_on_the_direction(name):
    model = build_model(name, BOX, **({"res_init": 16} if name == "vmgrid" else {"width": 32}))
    _randomise(model)
    assert model.options["view_dependent"] is True
    x, dirs = _points_and_directions()
    with torch.no_grad():
        for fn in _colour_fns(model):
            assert (fn(x, dirs[0]) - fn(x, dirs[1])).abs().max() > 1e-3


def test_the_option_turns_it_off_on_the_plain_methods_too():
    for name in ("vmgrid", "nerf"):
        model = build_model(
            name, BOX, view_dependent=False, **({"res_init": 16} if name == "vmgrid" else {"width": 32})
        )
        _randomise(model)
        x, dirs = _points_and_directions(m=16, k=2)
        with torch.no_grad():
            for fn in _colour_fns(model):
                assert torch.equal(fn(x, dirs[0]), fn(x, dirs[1]))


def test_default_networks_keep_their_shapes():
    """The default direction input is as before the option: vmgrid's 2 frequencies (3 * 5 = 15 columns
    beside the 27 appearance features), nerf's 4 (3 * 9 = 27 beside the trunk width)."""
    assert build_model("vmgrid", BOX, res_init=16).field.mlp[0].in_features == 27 + 15
    assert build_model("nerf", BOX, width=32).coarse.rgb_head[0].in_features == 32 + 27
    assert build_model("nerf-nope", BOX, width=32).coarse.rgb_head[0].in_features == 32 + 3
    assert build_model("nerf-noview", BOX, width=32).coarse.rgb_head[0].in_features == 32


def test_direction_encoding_off_is_empty():
    enc = direction_encoding(4, view_dependent=False)
    assert enc.out_dim == 0 and enc(torch.ones(5, 3)).shape == (5, 0)
    assert direction_encoding(0).out_dim == 3  # 0 frequencies still pass the raw direction: not "off"
