"""The image encoder every architecture puts in front of its feature extractor when a task's
state is an image (`TaskInfo.image_shape`).

A state is [image pixels (H*W*C, row-major H, W, C, values 0..255), vector (v)]. The encoder is
one convolution whose kernel is its stride (a "patch" layer, as a vision transformer's patch
embedding): the image is cut into (H/p) x (W/p) patches of p x p x C pixels, each mapped by the
same FC layer to `patch_channels` values and a ReLU; the patches' outputs, flattened, and the
vector form the feature extractor's input:

    e = ReLU(patches(x_img) W_e^T + b_e)      (P, c), P = (H/p)(W/p)
    FE input = [flatten(e), x_vec]            (P c + v)

so the feature extractor's first FC layer reads every patch's channels at its place (what a
convolutional encoder's final flatten + FC does). Written as a reshape and a matrix product, the
K members of an ensemble run it as one batched product (`MILEnsemble`), and the online stepper
as a NumPy one; it is trained end to end with the rest of the model. Pixels are normalised as
(x - 127.5) / 127.5 (a fixed shift and scale, `IMAGE_SHIFT`, not the training split's), folded
into the layer's weights (`pixel_weights`); the input normalisation buffers apply to the vector.
Cost per frame and member: P * p*p*C * c multiply-adds (32 x 32 x 3, p 4, c 8: 24,576). The
patch side is `default_patch` of the image's size (~8 x 8 patches).
"""

from __future__ import annotations

import math

import numpy as np
import torch

#: what a pixel value is shifted and divided by (0..255 -> -1..1)
IMAGE_SHIFT = 127.5


def patch_grid(x, image_shape: tuple, patch: int):
    """An image's pixels x (..., H*W*C) viewed as (..., H/p, W/p, p, p, C) (no copy); torch
    tensors or NumPy arrays alike."""
    h, w, c = image_shape
    lead = tuple(x.shape[:-1])
    n = len(lead)
    grid = x.reshape(*lead, h // patch, patch, w // patch, patch, c)
    order = (*range(n), n, n + 2, n + 1, n + 3, n + 4)
    return grid.permute(order) if isinstance(x, torch.Tensor) else grid.transpose(order)


def patches(x, image_shape: tuple, patch: int):
    """An image's patches: x (..., H*W*C) -> (..., (H/p)(W/p), p*p*C), patches in row-major
    order, each one's pixels row-major (p, p, C); torch tensors or NumPy arrays alike."""
    h, w, c = image_shape
    return patch_grid(x, image_shape, patch).reshape(*x.shape[:-1], (h // patch) * (w // patch), patch * patch * c)


def default_patch(height: int, width: int) -> int:
    """The patch side the models take for an image of height x width: the largest that divides
    both and leaves at least 8 patches across the shorter side (32 x 32: 4, 64 x 64: 8, 96 x 96:
    12, 84 x 84: 7), so the encoder's output (P * c values) stays ~64 patches whatever the size;
    ValueError (one line) where none leaves at most 16 across (e.g. 97 x 97: resize it)."""
    common = math.gcd(int(height), int(width))
    limit = max(1, min(height, width) // 8)
    patch = max(d for d in range(1, limit + 1) if common % d == 0)
    if min(height, width) // patch > 16:
        raise ValueError(f"an image of {height} x {width} pixels has no patch size that leaves 8-16 patches "
                         f"across: resize it (a task spec's image=HxW, e.g. image=64x64)")
    return patch


def check_image_config(image_shape: tuple, patch: int, patch_channels: int, input_size: int) -> None:
    """ValueError (one line) unless an image of `image_shape` cut into `patch`-pixel patches fits
    a state of `input_size` values."""
    if len(image_shape) != 3 or min(image_shape) < 1:
        raise ValueError(f"an image shape is (H, W, C), positive, got {tuple(image_shape)}")
    h, w, c = image_shape
    if patch < 1 or h % patch or w % patch:
        raise ValueError(f"the encoder's patch size {patch} must divide the image's {h} x {w} pixels")
    if patch_channels < 1:
        raise ValueError(f"the encoder needs at least one channel per patch, got {patch_channels}")
    if h * w * c > input_size:
        raise ValueError(f"an image of {h} x {w} x {c} = {h * w * c} values does not fit a state of {input_size}")


def encoded_size(image_shape: tuple, patch: int, patch_channels: int, input_size: int) -> int:
    """The feature extractor's input size: the patches' channels and the vector part."""
    h, w, c = image_shape
    return (h // patch) * (w // patch) * patch_channels + input_size - h * w * c


def pixel_weights(weight, bias) -> tuple:
    """The encoder's FC layer applied to raw pixels: (W / IMAGE_SHIFT, b - sum_j W_j), so that
    raw @ W'^T + b' = ((raw - IMAGE_SHIFT) / IMAGE_SHIFT) @ W^T + b (no pass over the pixels to
    normalise them). weight (..., c, ppC), bias (..., c); torch or NumPy."""
    return weight / IMAGE_SHIFT, bias - weight.sum(-1)


def encode_numpy(x: np.ndarray, weight: np.ndarray, bias: np.ndarray, vector: np.ndarray,
                 image_shape: tuple, patch: int) -> np.ndarray:
    """The encoder on one raw state x (d,) with `pixel_weights` (c, ppC) / (K, c, ppC) and (c,) /
    (K, c), followed by the normalised vector part (v,) / (K, v): the feature extractor's input,
    (encoded,) or (K, encoded)."""
    values = int(np.prod(image_shape))
    p = patches(x[:values], image_shape, patch)  # (P, ppC)
    e = np.maximum(p @ np.swapaxes(weight, -1, -2) + bias[..., None, :], 0.0)  # (P, c) or (K, P, c)
    e = e.reshape(*e.shape[:-2], -1)
    return np.concatenate([e, np.broadcast_to(vector, (*e.shape[:-1], vector.shape[-1]))], axis=-1)


#: float32 values of pixels a chunk of `PatchLayer` converts at a time (1 MB: stays in cache)
CHUNK_VALUES = 2 ** 18


class PatchLayer(torch.autograd.Function):
    """ReLU(patches @ W_m^T + b_m) for each member m: pixels (K, N, P, ppC), the instances' patches
    (any dtype: uint8 as a dataset stores them; no gradient), weight (K, c, ppC), bias (K, c) ->
    (K, N*P, c). The pixels are converted to float32 a chunk of instances at a time
    (`CHUNK_VALUES`) and each chunk's product is written into the one output; the backward
    converts them again for the weight gradient, accumulated chunk by chunk. No float32 copy of
    a batch's pixels is made (118 MB a step for 3 members of 32 Key bags: writing it and reading it
    twice cost more than converting in cache twice, 54 -> 33 ms a step on key_pixels). The
    weight gradient of one product over all the rows as a batched product ran ~5x slower; a
    stack of the members' outputs and a separate ReLU each cost another pass over them."""

    @staticmethod
    def forward(ctx, pixels: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        K, N, P, D = pixels.shape
        out = torch.empty(K, N * P, weight.shape[1])
        for m, start, stop, chunk in _chunks(pixels):
            torch.mm(chunk, weight[m].t(), out=out[m, start * P:stop * P])
        out.add_(bias[:, None, :]).clamp_(min=0.0)
        ctx.save_for_backward(pixels, out)
        return out

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        pixels, out = ctx.saved_tensors
        P = pixels.shape[2]
        grad = torch.ops.aten.threshold_backward(grad, out, 0.0)
        weight_grad = grad.new_zeros(grad.shape[0], grad.shape[2], pixels.shape[3])
        for m, start, stop, chunk in _chunks(pixels):
            weight_grad[m].addmm_(grad[m, start * P:stop * P].t(), chunk)
        return None, weight_grad, grad.sum(1)


def _chunks(pixels: torch.Tensor):
    """(member, first instance, end instance, that chunk's patches as float32 (n * P, ppC)) over
    pixels (K, N, P, ppC), `CHUNK_VALUES` values at a time, in one reused buffer."""
    K, N, P, D = pixels.shape
    step = max(1, CHUNK_VALUES // (P * D))
    buffer = torch.empty(min(step, N) * P * D)
    for m in range(K):
        for start in range(0, N, step):
            stop = min(start + step, N)
            chunk = buffer[:(stop - start) * P * D].view(stop - start, P, D)
            chunk.copy_(pixels[m, start:stop])
            yield m, start, stop, chunk.view(-1, D)
