"""Dropout masks per ensemble member and the fused ReLU + dropout (nmrm_ros.mil.dropout)."""

import numpy as np
import pytest
import torch

from nmrm_ros.mil.dropout import MemberDropout, relu_dropout

WIDTHS = [6, 4, 2]


def test_a_members_masks_do_not_depend_on_the_other_members():
    """Member 1 of three draws what a one-member MemberDropout with its seed draws, step after
    step, even when the other members' bags are longer (its padding is left unmasked)."""
    three = MemberDropout(0.3, [5, 7, 9], WIDTHS)
    alone = MemberDropout(0.3, [7], WIDTHS)
    for steps in ([4, 3, 5], [2, 2, 2], [1, 4, 3]):
        together = three.take(3, steps)
        own = alone.take(3, [steps[1]])
        for mask, mine, width in zip(together, own, WIDTHS):
            mask = mask.view(3, 3, max(steps), width)[1]
            assert torch.equal(mask[:, :steps[1]], mine.view(3, steps[1], width))
            assert torch.all(mask[:, steps[1]:] == np.float32(1 / 0.7))  # padding: not dropped


def test_masks_are_inverted_dropout_at_rate_p():
    masks = MemberDropout(0.25, [0, 1], [64]).take(50, [40, 40])[0]
    assert masks.shape == (2, 50 * 40, 64)
    values = set(torch.unique(masks).tolist())
    assert values == {0.0, float(np.float32(1 / 0.75))}
    dropped = float((masks == 0).float().mean())
    assert abs(dropped - 0.25) < 0.005  # 256,000 draws: 5 standard deviations is 0.0043
    assert not torch.equal(masks[0], masks[1])  # two members, two streams


def test_the_streams_advance_by_exactly_the_draws_of_each_step():
    """Two steps drawn one by one equal the words of one long draw cut in the same places."""
    masks = MemberDropout(0.5, [3], [4])
    first = masks.take(2, [3])[0].clone()  # the next take writes into the same buffer
    second = masks.take(2, [3])[0].clone()
    stream = np.random.SFC64(np.random.SeedSequence([3, 0xD80]))
    words = stream.random_raw(12).view(np.int16)
    expected = (torch.from_numpy(words.copy()) >= 0).float() * 2.0
    assert torch.equal(first.view(-1), expected[:24])
    assert torch.equal(second.view(-1), expected[24:])


def test_a_step_asks_for_one_length_per_member():
    with pytest.raises(ValueError, match="2 members need 2 step counts"):
        MemberDropout(0.1, [0, 1], WIDTHS).take(4, [3])


def test_relu_dropout_equals_relu_times_mask_forward_and_backward():
    torch.manual_seed(0)
    z = torch.randn(3, 40, 8, dtype=torch.float64, requires_grad=True)
    mask = (torch.rand(3, 40, 8, dtype=torch.float64) > 0.2).to(torch.float64) / 0.8
    weight = torch.randn(3, 40, 8, dtype=torch.float64)
    fused = relu_dropout(z, mask, 1 / 0.8)
    (grad_fused,) = torch.autograd.grad((fused * weight).sum(), z)
    plain = torch.relu(z) * mask
    (grad_plain,) = torch.autograd.grad((plain * weight).sum(), z)
    assert torch.equal(fused, plain)
    assert torch.allclose(grad_fused, grad_plain, rtol=0, atol=1e-15)
    assert torch.autograd.gradcheck(lambda t: relu_dropout(t, mask, 1 / 0.8), (z,))
