"""engine.rollback.step_values: the trainer's loss, mse and gradient check read in one transfer."""
import torch

from nerf_core.engine.rollback import gradient_problem, step_values


def _opt_with_grads(*grads):
    params = [torch.nn.Parameter(torch.zeros_like(g)) for g in grads]
    for p, g in zip(params, grads):
        p.grad = g.clone()
    return torch.optim.Adam(params), params


def test_values_and_a_finite_gradient():
    opt, params = _opt_with_grads(torch.tensor([3.0, 4.0]), torch.tensor([[1.0]]))
    loss, mse = torch.tensor(0.25), torch.tensor(0.125)
    assert step_values(loss, mse, opt) == (0.25, 0.125, None)
    assert gradient_problem(opt) is None
    assert torch.equal(params[0].grad, torch.tensor([3.0, 4.0]))  # nothing written back


def test_nan_or_inf_gradient_is_named_like_gradient_problem():
    for bad in (float("nan"), float("inf")):
        opt, _ = _opt_with_grads(torch.tensor([1.0, bad]), torch.tensor([2.0]))
        _, _, why = step_values(torch.tensor(1.0), torch.tensor(1.0), opt)
        assert why == gradient_problem(opt) == "gradient is NaN or inf"


def test_no_gradients_yet_is_no_problem():
    opt, params = _opt_with_grads(torch.tensor([1.0]))
    params[0].grad = None
    assert step_values(torch.tensor(2.0), torch.tensor(1.0), opt) == (2.0, 1.0, None)
