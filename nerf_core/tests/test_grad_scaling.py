"""Gradient scaling by distance (nerf_core.volume.grad_scaling): forward is the identity, backward scales."""
import torch

from nerf_core.volume import grad_scaling


def test_distance_scale_hand_computed():
    t = torch.tensor([0.0, 0.5, 1.0, 2.0, 4.0])
    # min(1, (t / 2)^2): 0, 1/16, 1/4, 1, 1
    assert torch.allclose(grad_scaling.distance_scale(t, 2.0), torch.tensor([0.0, 0.0625, 0.25, 1.0, 1.0]))


def test_forward_identity_backward_scaled():
    x = torch.tensor([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], requires_grad=True)
    s = torch.tensor([0.5, 0.0, 2.0])
    y = grad_scaling.scale_gradient(x, s)
    assert torch.equal(y, x.detach())
    (y * torch.tensor([1.0, 10.0])).sum().backward()
    assert torch.allclose(x.grad, torch.tensor([[0.5, 5.0], [0.0, 0.0], [2.0, 20.0]]))


def test_one_dimensional_input():
    x = torch.tensor([1.0, 2.0], requires_grad=True)
    grad_scaling.scale_gradient(x, torch.tensor([0.25, 1.0])).pow(2).sum().backward()
    assert torch.allclose(x.grad, torch.tensor([0.5, 4.0]))  # d(x^2)/dx = 2x, times the scale


def _recorded_scales(monkeypatch, origin, method="vmgrid", **options):
    """The per-sample gradient scales vmgrid's render_rays asks for, with their sample distances."""
    from nerf_core.methods.registry import build_model

    seen = []
    real = grad_scaling.scale_gradient

    def spy(x, scale):
        seen.append(scale.detach().clone())
        return real(x, scale)

    monkeypatch.setattr(grad_scaling, "scale_gradient", spy)
    torch.manual_seed(0)
    aabb = torch.tensor([[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]])
    model = build_model(method, aabb, **options)
    n = 64
    rays_o = torch.tensor(origin, dtype=torch.float32).expand(n, 3).contiguous()
    rays_d = torch.nn.functional.normalize(torch.randn(n, 3), dim=-1)
    near, far = model.ray_interval(rays_o, rays_d, 0.0, 100.0)
    out = model.render_rays(rays_o, rays_d, near, far, torch.rand(n, 3), training=True)
    out["rgb"].sum().backward()
    return seen


def test_vmgrid_scales_gradients_near_a_camera_inside_the_box(monkeypatch):
    seen = _recorded_scales(monkeypatch, [0.0, 0.0, 0.0])
    assert seen, "vmgrid did not scale gradients for a camera inside the box"
    scale = seen[0]
    reach = grad_scaling.DEFAULT_REACH_SHARE * float(torch.tensor([4.0, 4.0, 4.0]).norm())  # share of the diagonal
    assert scale.min() < 0.05  # the first samples, a step from the lens, barely learn
    assert scale.max() == 1.0  # samples beyond the reach learn as before
    assert 0 < reach < 2.0  # the camera at the centre sees the box's walls 2 m away: some samples lie beyond


def test_vmgrid_leaves_cameras_outside_the_box_alone(monkeypatch):
    # Every sample lies beyond the reach, so no scaling op is even inserted: bit-identical training.
    assert _recorded_scales(monkeypatch, [0.0, 0.0, 6.0]) == []
    # and the option turns it off entirely
    assert _recorded_scales(monkeypatch, [0.0, 0.0, 0.0], grad_reach=0.0) == []


def test_nerf_scales_both_passes_near_a_camera_inside_the_box(monkeypatch):
    # hierarchical: coarse and fine pass, density and colour each: four scaled tensors
    small = dict(method="nerf", n_coarse=8, n_fine=8, width=16, sampler="hierarchical")
    seen = _recorded_scales(monkeypatch, [0.0, 0.0, 0.0], **small)
    assert len(seen) == 4 and all(float(s.min()) < 0.05 for s in seen)
    assert _recorded_scales(monkeypatch, [0.0, 0.0, 6.0], **small) == []
    # occupancy sampler: one network, density and colour
    seen = _recorded_scales(monkeypatch, [0.0, 0.0, 0.0], method="nerf", width=16)
    assert len(seen) == 2 and all(float(s.min()) < 0.05 for s in seen)
    assert _recorded_scales(monkeypatch, [0.0, 0.0, 6.0], method="nerf", width=16) == []


def test_near_camera_gate_checks_early_then_only_when_told_and_stays_on_once_near():
    gate = grad_scaling.NearCameraGate()
    far_t, near_t = torch.tensor([3.0, 4.0]), torch.tensor([0.5, 4.0])
    for _ in range(gate.CHECK_FIRST):
        assert gate.scales(far_t, 2.0) is None
    assert gate.checks == gate.CHECK_FIRST
    assert gate.scales(near_t, 2.0) is None  # not checked any more: no host read
    assert gate.checks == gate.CHECK_FIRST
    gate.recheck()
    assert torch.equal(gate.scales(near_t, 2.0), torch.tensor([0.0625, 1.0]))
    # from now on every batch is scaled; far samples by exactly 1 (bit-identical gradients)
    assert torch.equal(gate.scales(far_t, 2.0), torch.tensor([1.0, 1.0]))
    assert gate.scales(far_t, 0.0) is None  # the option off
