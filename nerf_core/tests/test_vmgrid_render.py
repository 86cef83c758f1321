"""vmgrid's training statistics stay on the device between periodic reads (methods.vmgrid_render)."""
import torch

from nerf_core.methods import vmgrid_render
from nerf_core.methods.registry import build_model


def _model():
    return build_model("vmgrid", torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), res_init=16, res_final=16)


def test_running_opacity_on_the_device_equals_the_hosts_running_mean():
    model = _model()
    host = 0.0
    gen = torch.Generator().manual_seed(0)
    for _ in range(20):
        acc = torch.rand(64, generator=gen)
        vmgrid_render.track_opacity(model, acc)
        host = 0.9 * host + 0.1 * float(acc.mean())  # what the step computed on the host before
    assert model._acc_ema == 0.0  # not read back yet: formed() sees the last periodic read
    assert vmgrid_render.read_opacity(model) == host and model._acc_ema == host


def test_a_value_set_on_the_host_is_where_the_device_continues_from():
    model = _model()
    vmgrid_render.track_opacity(model, torch.full((8,), 0.5))
    model.set_replica_stats({"acc_ema": 0.95})
    vmgrid_render.track_opacity(model, torch.ones(8))
    assert vmgrid_render.read_opacity(model) == 0.9 * 0.95 + 0.1 * 1.0
    assert model.replica_stats() == {"acc_ema": 0.9 * 0.95 + 0.1 * 1.0}
