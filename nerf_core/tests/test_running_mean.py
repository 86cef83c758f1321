"""vmgrid's training statistics stay on the device between periodic reads (utils.running_mean)."""
import torch

from nerf_core.methods.registry import build_model
from nerf_core.utils.running_mean import RunningMean


def _model():
    return build_model("vmgrid", torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), res_init=16, res_final=16)


def test_running_mean_on_the_device_equals_the_hosts_running_mean():
    mean = RunningMean(0.0)
    host = 0.0
    gen = torch.Generator().manual_seed(0)
    for _ in range(20):
        acc = torch.rand(64, generator=gen)
        mean.add(acc)
        host = 0.9 * host + 0.1 * float(acc.mean())  # what the step computed on the host before
    assert mean.value == 0.0  # not read back yet: formed() sees the last periodic read
    assert mean.read() == host and mean.value == host
    mean.add(torch.zeros(0))  # an empty batch changes nothing
    assert mean.read() == host


def test_vmgrid_reads_its_opacity_only_when_asked_and_continues_from_a_value_set_on_the_host():
    model = _model()
    model.opacity.add(torch.full((8,), 0.5))
    assert not model.formed() and model.opacity.value == 0.0
    model.set_replica_stats({"acc_ema": 0.95})
    model.opacity.add(torch.ones(8))
    assert model.opacity.read() == 0.9 * 0.95 + 0.1 * 1.0
    assert model.replica_stats() == {"acc_ema": 0.9 * 0.95 + 0.1 * 1.0}
