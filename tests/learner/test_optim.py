"""The optimiser machinery: the fused Adam step against torch.optim.Adam, and the clipping."""

from __future__ import annotations

import pytest
import torch

from seal.learner.optim import AdamCache, Slots, clip_grad_norm, fused_adam_step


def _loss(w: list[torch.nn.Parameter], x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    return ((torch.relu(x @ w[0] + w[1]) @ w[2] - y) ** 2).mean()


def test_slots_step_matches_torch_adam_step_for_step_with_clipping() -> None:
    """An agent's optimiser step (`Slots`: autograd, clipping, the fused Adam) against the plain
    recipe: loss.backward(), nn.utils.clip_grad_norm_ and torch.optim.Adam (not fused, the same
    lr, betas and eps), over 20 steps of a small regression whose gradients are clipped at first."""
    gen = torch.Generator().manual_seed(0)
    shapes = [(5, 4), (4,), (4, 1)]
    ours = [torch.nn.Parameter(torch.randn(*s, generator=gen)) for s in shapes]
    ref = [torch.nn.Parameter(p.detach().clone()) for p in ours]
    slots = Slots([["e"]], [ours], lr=1e-2, eps=1e-5, max_grad_norm=1.0)
    adam = torch.optim.Adam(ref, lr=1e-2, eps=1e-5)
    cache: AdamCache = {}
    clipped = 0
    for _ in range(20):
        x, y = torch.randn(16, 5, generator=gen), torch.randn(16, 1, generator=gen)

        slots.step(["e"], slots.grads(_loss(ours, x, y), ["e"]), cache)
        adam.zero_grad()
        _loss(ref, x, y).backward()
        clipped += float(torch.nn.utils.clip_grad_norm_(ref, 1.0)) > 1.0
        adam.step()
        for a, b in zip(ours, ref, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-6)
    assert clipped > 0  # the clipping was exercised
    assert float(slots.optimizers[0].state[ours[0]]["step"]) == 20.0


def test_clip_grad_norm_is_torchs_and_keeps_missing_gradients() -> None:
    gen = torch.Generator().manual_seed(1)
    grads = [torch.randn(3, 2, generator=gen) * 5, None, torch.randn(4, generator=gen)]
    params = [torch.nn.Parameter(torch.zeros_like(g)) for g in grads if g is not None]
    for p, g in zip(params, [g for g in grads if g is not None], strict=True):
        p.grad = g.clone()
    torch.nn.utils.clip_grad_norm_(params, 0.5)
    got = clip_grad_norm(grads, 0.5)
    assert got[1] is None
    torch.testing.assert_close(got[0], params[0].grad)
    torch.testing.assert_close(got[2], params[1].grad)
    assert clip_grad_norm([None], 0.5) == [None]
    assert torch.linalg.vector_norm(torch.cat([got[0].flatten(), got[2]])) == pytest.approx(
        0.5, rel=1e-5
    )


def test_fused_adam_step_matches_torch_adam_with_a_missing_gradient_and_a_reload() -> None:
    """`fused_adam_step` (cached fused calls) gives Adam(fused=True).step()'s parameters, bit for bit:
    over steps where one parameter has no gradient (left alone, its step count too), after a
    learning-rate change and after load_state_dict (the cached lists must follow the new states)."""
    gen = torch.Generator().manual_seed(0)
    ours = [torch.nn.Parameter(torch.randn(3, 2, generator=gen)) for _ in range(2)]
    ref = [torch.nn.Parameter(p.detach().clone()) for p in ours]
    opt_ours = torch.optim.Adam(ours, lr=1e-2, fused=True, eps=1e-5)
    opt_ref = torch.optim.Adam(ref, lr=1e-2, fused=True, eps=1e-5)
    cache: AdamCache = {}
    for step in range(6):
        grads = [torch.randn(3, 2, generator=gen) for _ in range(2)]
        if step in (2, 3):
            grads[1] = None  # unused this step
        if step == 4:
            for opt in (opt_ours, opt_ref):
                opt.param_groups[0]["lr"] = 3e-3
                opt.load_state_dict(opt.state_dict())
        for p, g in zip(ref, grads, strict=True):
            p.grad = g
        opt_ref.step()
        fused_adam_step([opt_ours], grads, cache)
        for a, b in zip(ours, ref, strict=True):
            assert torch.equal(a, b), step
    assert [float(opt_ours.state[p]["step"]) for p in ours] == [6.0, 4.0]
    assert [float(opt_ref.state[p]["step"]) for p in ref] == [6.0, 4.0]
