"""vm_products: the native CPU kernel against grid_sample and against values worked out by hand; its
fallbacks; and the channels-last grid storage that it reads (old checkpoints still load)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest
import torch

from nerf_core.fields import tensorf, vm_products as vp
from nerf_core.fields.tensorf import TensorVMField
from nerf_core.methods.registry import build_model
from nerf_core.utils import native

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
HAS_CC = any(shutil.which(c) for c in ("cc", "gcc", "clang")) and sys.platform != "win32"


def _native():
    if vp.backend()[0] != "native":
        pytest.skip(f"no native kernel here: {vp.backend()[1]}")


def test_the_native_kernel_builds_where_there_is_a_compiler():
    # CI machines have gcc: there the fast path must really be taken, not skipped in silence.
    if not HAS_CC or not native.enabled():
        pytest.skip("no C compiler, or NERF_CORE_NATIVE=0")
    assert vp.backend() == ("native", ""), vp.backend()


def test_one_point_by_hand():
    """Plane 0 spans (x, y), its line z. On a 3-cell grid, u = (0.5, -0.5, 0) is cell (1.5, 0.5) of
    the plane and node 1 of the line: the mean of the four plane texels around it times line[1]."""
    _native()
    planes = torch.zeros(3, 1, 3, 3)
    planes[0, 0] = torch.tensor([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]])  # [row = y, col = x]
    lines = torch.zeros(3, 1, 3, 1)
    lines[0, 0, :, 0] = torch.tensor([10.0, 20.0, 30.0])
    u = torch.tensor([[0.5, -0.5, 0.0]])
    out = vp.vm_products(planes, lines, u)  # (1, 3, 1)
    # x = 0.5 -> column 1.5, y = -0.5 -> row 0.5: texels (0,1)=2, (0,2)=3, (1,1)=5, (1,2)=6, weights 1/4.
    assert out.shape == (1, 3, 1)
    assert out[0, 0, 0].item() == pytest.approx((2 + 3 + 5 + 6) / 4 * 20.0)
    assert out[0, 1:].abs().max().item() == 0.0


@pytest.mark.parametrize("threads", [1, 2, 3])
@pytest.mark.parametrize("r,n,m", [(1, 2, 7), (5, 7, 300), (16, 33, 2000)])
def test_native_equals_grid_sample_forward_and_gradients(threads, r, n, m):
    _native()
    g = torch.Generator().manual_seed(r * 100 + n)
    planes = torch.randn(3, r, n, n, generator=g, requires_grad=True)
    lines = torch.randn(3, r, n, 1, generator=g, requires_grad=True)
    u = torch.rand(m, 3, generator=g) * 2.4 - 1.2  # some points outside the grid: zero padding
    u[:3] = torch.tensor([[1.0, -1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, 1.0, 1.0]])  # exact corners
    grad = torch.randn(m, 3, r, generator=g)
    grad[: m // 3] = 0  # unused samples
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        ref = vp.reference(planes, lines, u)
        ref_gp, ref_gl = torch.autograd.grad(ref, (planes, lines), grad)
        out = vp._NativeVMProducts.apply(planes, lines, u)
        gp, gl = torch.autograd.grad(out, (planes, lines), grad)
    finally:
        torch.set_num_threads(before)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(gp, ref_gp, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(gl, ref_gl, rtol=1e-5, atol=1e-4)


def test_without_autograd_the_forward_runs_in_chunks(monkeypatch):
    _native()
    monkeypatch.setattr(vp, "NO_GRAD_CHUNK", 7)  # 100 points: 15 calls, the last one short
    g = torch.Generator().manual_seed(3)
    planes, lines = torch.randn(3, 4, 9, 9, generator=g), torch.randn(3, 4, 9, 1, generator=g)
    u = torch.rand(100, 3, generator=g) * 2 - 1
    with torch.no_grad():
        out = vp.vm_products(planes, lines, u)
    torch.testing.assert_close(out, vp.reference(planes, lines, u), rtol=1e-5, atol=1e-6)


def test_fallbacks_give_grid_sample():
    planes = torch.randn(3, 2, 5, 5, dtype=torch.float64)
    lines = torch.randn(3, 2, 5, 1, dtype=torch.float64)
    u = torch.rand(10, 3, dtype=torch.float64) * 2 - 1
    assert vp.backend(planes)[0] == "grid_sample"  # float64
    torch.testing.assert_close(vp.vm_products(planes, lines, u), vp.reference(planes, lines, u), rtol=0, atol=0)
    u32 = u.float().requires_grad_(True)
    assert vp.backend(planes.float(), u32) == ("grid_sample", "a gradient with respect to the points is needed")


def test_shapes_the_kernel_does_not_index_go_to_grid_sample():
    """The kernel indexes raw memory as (3, N, N, R): non-square planes (a crafted checkpoint) must
    never reach it."""
    _native()
    planes, lines = torch.randn(3, 2, 5, 9), torch.randn(3, 2, 5, 1)
    u = torch.rand(20, 3) * 2 - 1
    with torch.no_grad():
        torch.testing.assert_close(vp.vm_products(planes, lines, u), vp.reference(planes, lines, u), rtol=0, atol=0)
    assert not vp._kernel_shapes_ok(torch.randn(3, 2, 5, 5), torch.randn(3, 2, 6, 1), u)
    assert vp._kernel_shapes_ok(torch.randn(3, 2, 5, 5), torch.randn(3, 2, 5, 1), u)


def test_turned_off_by_the_environment(monkeypatch):
    monkeypatch.setenv("NERF_CORE_NATIVE", "0")
    assert vp.backend() == ("grid_sample", "turned off by NERF_CORE_NATIVE")


def test_no_compiler_or_a_failed_build_falls_back_with_a_reason(tmp_path, monkeypatch):
    src = tmp_path / "k.c"
    src.write_text("int f(void) { return 1; }\n")
    monkeypatch.setattr(native, "_loaded", {})
    monkeypatch.setattr(native, "_compiler", lambda: None)
    assert native.load(src) == (None, "no C compiler (cc, gcc or clang) on PATH")
    if not HAS_CC:
        return
    monkeypatch.undo()  # the real compiler again
    monkeypatch.setattr(native, "_loaded", {})
    bad = tmp_path / "bad.c"
    bad.write_text("this is not C\n")
    monkeypatch.setenv("NERF_CORE_CACHE", str(tmp_path / "cache"))
    lib, why = native.load(bad)
    assert lib is None and "failed on bad.c" in why
    # A cache folder that cannot be made (a file is in the way): no library, a reason, no traceback.
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    monkeypatch.setenv("NERF_CORE_CACHE", str(blocker / "sub"))
    lib, why = native.load(src)
    assert lib is None and why


def test_the_build_is_cached_by_source_and_reused(tmp_path, monkeypatch):
    if not HAS_CC:
        pytest.skip("no C compiler")
    monkeypatch.setenv("NERF_CORE_CACHE", str(tmp_path))
    monkeypatch.setattr(native, "_loaded", {})
    src = tmp_path / "k.c"
    src.write_text("int f(void) { return 41; }\n")
    lib, why = native.load(src)
    assert why == "" and lib.f() == 41
    built = sorted(tmp_path.glob("k-*.so"))
    assert len(built) == 1 and not list(tmp_path.glob("*.tmp"))
    # Another process (the cache, not this one's memory) loads the same file without building.
    code = ("import sys; from nerf_core.utils import native; lib, why = native.load(sys.argv[1]); "
            "print(lib.f() if lib else why)")
    proc = subprocess.run([sys.executable, "-c", code, str(src)], capture_output=True, text=True,
                          env={**os.environ, "NERF_CORE_CACHE": str(tmp_path), "CC": "/nonexistent-cc"})
    assert proc.stdout.strip() == "41", proc.stderr
    src.write_text("int f(void) { return 42; }\n")  # an edit rebuilds
    monkeypatch.setattr(native, "_loaded", {})
    assert native.load(src)[0].f() == 42 and len(list(tmp_path.glob("k-*.so"))) == 2


# -- the channels-last storage ------------------------------------------------------------------

def test_grids_are_stored_contiguous_channels_last_and_stay_so():
    f = TensorVMField(BOX, resolution=8, density_rank=3, app_rank=5)
    assert f.density_planes_cl.shape == (3, 8, 8, 3) and f.app_lines_cl.shape == (3, 8, 5)
    assert f.density_planes.shape == (3, 3, 8, 8) and f.app_lines.shape == (3, 5, 8, 1)  # views
    f.upsample(12)
    assert all(p.is_contiguous() for p in f.grid_parameters())  # what fused Adam needs to run without copies
    assert f.app_planes_cl.shape == (3, 12, 12, 5)


def _old_layout(state: dict, prefix: str = "") -> dict:
    """A state dict as saved before the channels-last storage."""
    old = dict(state)
    for name in tensorf.GRID_NAMES:
        v = old.pop(prefix + tensorf.STORED[name])
        old[prefix + name] = v.permute(0, 3, 1, 2) if v.dim() == 4 else v.permute(0, 2, 1).unsqueeze(-1)
    return {k: v.contiguous() for k, v in old.items()}


def test_a_checkpoint_from_before_the_layout_change_loads_to_the_same_field():
    model = build_model("vmgrid", BOX, res_init=16)
    with torch.no_grad():
        for p in model.field.grid_parameters():
            p.normal_()
    model.field.upsample(20)  # grown: the loader must grow the fresh model from the old key's shape
    x = torch.rand(50, 3) * 2 - 1
    d = torch.nn.functional.normalize(torch.randn(50, 3), dim=-1)
    with torch.no_grad():
        want = model.field.density(x), model.field.color(x, d)
    old = _old_layout(model.state_dict(), "field.")
    assert "field.density_planes" in old and old["field.density_planes"].shape == (3, 16, 20, 20)
    fresh = build_model("vmgrid", BOX, res_init=16)
    weights, _ = fresh.upgrade_checkpoint(old)
    assert "field.density_planes" in old  # the caller's dict is not changed
    from nerf_core.runs.checkpoint_checks import check_weights
    check_weights(fresh, weights, "old.pt")
    fresh.load_state_dict(old)  # also straight from the old dict
    with torch.no_grad():
        got = fresh.field.density(x), fresh.field.color(x, d)
    assert torch.equal(got[0], want[0]) and torch.equal(got[1], want[1])


def test_old_adam_moments_are_upgraded_for_resume():
    from nerf_core.engine.optim import make_optimizer

    model = build_model("vmgrid", BOX, res_init=12)
    opt = make_optimizer(model, 1e-3)
    x = torch.rand(64, 3) * 2 - 1
    (model.field.density(x).sum() + model.field.color(x, torch.nn.functional.normalize(x, dim=-1)).sum()).backward()
    opt.step()
    state = opt.state_dict()
    ids = state["param_groups"][0]["params"]
    old_state = {**state, "state": dict(state["state"])}
    for pid, p in zip(ids, model.field.grid_parameters()):
        old_state["state"][pid] = {
            k: (v.permute(0, 3, 1, 2) if v.dim() == 4 else v.permute(0, 2, 1).unsqueeze(-1))
            if torch.is_tensor(v) and v.dim() >= 3
            else v
            for k, v in state["state"][pid].items()
        }
    old_weights = _old_layout(model.state_dict(), "field.")
    _, upgraded = model.upgrade_checkpoint(old_weights, old_state)
    opt.check_state(upgraded, "old.pt")
    for pid in ids:
        for k, v in state["state"][pid].items():
            assert torch.equal(upgraded["state"][pid][k], v)


def test_training_steps_match_between_the_kernel_and_grid_sample(monkeypatch):
    _native()
    from nerf_core.engine.optim import make_optimizer

    def run(native_on: bool):
        monkeypatch.setenv("NERF_CORE_NATIVE", "1" if native_on else "0")
        torch.manual_seed(0)
        model = build_model("vmgrid", BOX, res_init=16)
        opt = make_optimizer(model, 1e-2)
        gen = torch.Generator().manual_seed(1)
        for _ in range(5):
            x = torch.rand(500, 3, generator=gen) * 2 - 1
            d = torch.nn.functional.normalize(torch.randn(500, 3, generator=gen), dim=-1)
            loss = model.field.density(x).mean() + model.field.color(x, d).square().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        return [p.detach().clone() for p in model.field.grid_parameters()]

    for a, b in zip(run(True), run(False)):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
