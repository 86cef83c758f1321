"""``derived_cache.DerivedCache`` rebuilds its value on every kind of change of its tensors, and only then."""
import copy
import io

import pytest
import torch

from nerf_core.utils.derived_cache import DerivedCache


def _cache(follow):
    cache, builds = DerivedCache(follow_optimizers=follow), []

    def get(tensors):
        def build():
            builds.append(1)
            return sum(float(t.detach().sum()) for t in tensors)
        return cache.get(tensors, build)
    return cache, builds, get


def test_in_place_change_and_replacement_rebuild_and_nothing_else_does():
    cache, builds, get = _cache(follow=False)
    a = torch.ones(4)
    assert get([a]) == 4.0 and get([a]) == 4.0 and len(builds) == 1
    b = torch.full((4,), 2.0)  # another tensor, same version, device and dtype: only identity tells
    assert (b._version, b.device, b.dtype) == (a._version, a.device, a.dtype)
    assert get([b]) == 8.0 and len(builds) == 2
    b.mul_(2.0)  # in place: the version counter moves
    assert get([b]) == 16.0 and len(builds) == 3
    assert get([b, a]) == 20.0 and len(builds) == 4  # a different list of tensors
    # Without follow_optimizers an optimiser step elsewhere changes nothing.
    p = torch.nn.Parameter(torch.ones(2))
    p.grad = torch.ones(2)
    torch.optim.SGD([p], lr=0.1).step()
    assert get([b, a]) == 20.0 and len(builds) == 4


@pytest.mark.parametrize("fused", [True, False])
def test_an_optimiser_step_rebuilds_even_when_no_version_moves(fused):
    cache, builds, get = _cache(follow=True)
    p = torch.nn.Parameter(torch.ones(3))
    opt = torch.optim.Adam([p], lr=0.5, fused=fused)
    assert get([p]) == 3.0
    version = p._version
    p.grad = torch.ones(3)
    opt.step()
    if fused:
        assert p._version == version  # why version counters alone are not enough
    assert get([p]) == pytest.approx(float(p.detach().sum())) and get([p]) < 3.0 and len(builds) == 2


def test_it_pickles_and_copies_empty():
    cache, builds, get = _cache(follow=True)
    a = torch.ones(2)
    get([a])
    assert not cache.empty
    buf = io.BytesIO()
    torch.save(cache, buf)  # weak references inside: they are left out
    buf.seek(0)
    for other in (torch.load(buf, weights_only=False), copy.deepcopy(cache)):
        assert other.empty and other.follow_optimizers
        assert other.get([a], lambda: "rebuilt") == "rebuilt"
    assert not cache.empty  # the original keeps its value
