"""K reward models of one architecture computed as one batched model (an ensemble).

    ens = MILEnsemble.from_members([build_model(cfg) for _ in range(K)])
    out = ens(x, lengths)     x: (B, T, d) shared by all members, or (K, B, T, d) a batch each
                              (float32, or uint8 where every input is a pixel);
                              lengths: (B,) or (K, B)
    out.returns (K, B)  out.rewards (K, B, T)  out.hidden (K, B, T, k)
    ens(x, lengths, members=idx)   only members idx (K',): x (K', B, T, d) or (B, T, d), outputs (K', ...)

Every member is exactly a `MILRewardModel` (`ens.member(m)` rebuilds it; tests check that the
ensemble forward equals each member's own forward). Each parameter of the single model becomes one
stacked tensor with a leading member axis: fully connected layers run as batched matrix products
(`torch.baddbmm`), and the K LSTMs (hidden size k each) run as one `torch.lstm` of hidden size K*k
whose weights are block-diagonal (member m's gates only see member m's features and state), so
the recurrence stays in torch's fused kernel. Gradients reach only the diagonal blocks, so training
the sum of the members' losses with Adam is K independent trainings done in one pass.

What the head sees and how its outputs become rewards is the architecture's rule
(`architectures.REGISTRY`); `_forward` branches on nothing else.

Normalisation buffers are per member (each member may train on its own split). `serving_member`
is the member whose hidden state the online model publishes (the best on validation).

A single model is an ensemble of one: training, checkpoints, evaluation and serving all work on a
`MILEnsemble` (`as_ensemble` turns a `MILRewardModel` into one), so there is one code path
whatever K is. `MILRewardModel` remains the reference definition of one member.
"""

from __future__ import annotations

import torch
from torch import nn

from .dropout import MemberDropout, dropout_mask, relu_dropout
from .image_encoder import PatchLayer, patches, pixel_weights
from .models import MILOutput, MILRewardModel, ModelConfig, build_model, output_activation


def _key(name: str) -> str:
    return name.replace(".", "__")


class MILEnsemble(nn.Module):
    """K members of one `ModelConfig`, parameters stacked on a leading member axis."""

    def __init__(self, config: ModelConfig, members: int) -> None:
        super().__init__()
        if members < 1:
            raise ValueError(f"an ensemble needs at least one member, got {members}")
        self.config = config
        self.members = int(members)
        template = build_model(config)
        self.rule = template.rule  # the architecture's rule: architectures.REGISTRY
        self.uses_lstm = template.uses_lstm
        self.uses_attention = template.uses_attention
        self.hidden_size = template.hidden_size
        self.params = nn.ParameterDict({
            _key(name): nn.Parameter(p.detach().unsqueeze(0).repeat(members, *([1] * p.dim())))
            for name, p in template.named_parameters()})
        self.register_buffer("input_shift", torch.zeros(members, config.input_size))
        self.register_buffer("input_scale", torch.ones(members, config.input_size))
        self.register_buffer("return_scale", torch.ones(()))
        self.register_buffer("serving_member", torch.zeros((), dtype=torch.int64))
        # names of the Linear layers, in order, with where a ReLU (+ dropout) follows
        self._fe = [n for n, m in template.feature_extractor.named_children() if isinstance(m, nn.Linear)]
        self._head = [n for n, m in template.head.named_children() if isinstance(m, nn.Linear)]
        self.dropout = float(config.dropout)
        #: per-member dropout masks (`seed_dropout`); None: masks from torch's generator
        self.dropout_masks: MemberDropout | None = None
        self._step_masks = None  # this forward's masks, one per activation in order
        self._computed = None  # this forward's members (None: all)
        self._patch_ordered = False  # this forward's pixels come in the encoder's order (BagTensors)

    # ----------------------------------------------------------------- members in and out
    @classmethod
    def from_members(cls, models: list) -> "MILEnsemble":
        """Stack trained or freshly initialised single models (same config) into an ensemble."""
        config = models[0].config
        if any(m.config != config for m in models):
            raise ValueError("ensemble members must share one model configuration")
        ens = cls(config, len(models))
        with torch.no_grad():
            for i, model in enumerate(models):
                ens.set_member(i, model)
        return ens

    @torch.no_grad()
    def set_member(self, index: int, model: MILRewardModel) -> None:
        """Copy a single model's weights and normalisation into member `index`."""
        for name, p in model.named_parameters():
            self.params[_key(name)][index].copy_(p)
        self.input_shift[index].copy_(model.input_shift)
        self.input_scale[index].copy_(model.input_scale)
        self.return_scale.copy_(model.return_scale)

    @torch.no_grad()
    def member(self, index: int) -> MILRewardModel:
        """Member `index` as a stand-alone `MILRewardModel` (eval mode)."""
        model = build_model(self.config)
        for name, p in model.named_parameters():
            p.copy_(self.params[_key(name)][index])
        model.set_normalisation(self.input_shift[index], self.input_scale[index],
                                float(self.return_scale))
        return model.eval()

    def member_state(self, index: int) -> dict:
        """A detached copy of member `index`'s parameters and normalisation (for best-epoch keeping)."""
        state = {k: v[index].detach().clone() for k, v in self.params.items()}
        state["input_shift"] = self.input_shift[index].clone()
        state["input_scale"] = self.input_scale[index].clone()
        return state

    @torch.no_grad()
    def load_member_state(self, index: int, state: dict) -> None:
        for k, v in self.params.items():
            v[index].copy_(state[k])
        self.input_shift[index].copy_(state["input_shift"])
        self.input_scale[index].copy_(state["input_scale"])

    def relu_layers(self) -> list:
        """Parameter-key prefixes ("feature_extractor__0", ...) of the FC layers a ReLU follows:
        every feature-extractor layer and the head's hidden ones."""
        return ([_key(f"feature_extractor.{n}") for n in self._fe]
                + [_key(f"head.{n}") for n in self._head[:-1]])

    def seed_dropout(self, seeds: list) -> None:
        """Give member k its own dropout stream, seeded by `seeds[k]` (training does this)."""
        if len(seeds) != self.members:
            raise ValueError(f"{self.members} members need {self.members} dropout seeds, got {len(seeds)}")
        widths = list(self.config.fe_sizes) + list(self.config.head_sizes)  # each ReLU's width, in order
        self.dropout_masks = MemberDropout(self.dropout, seeds, widths) if self.dropout > 0 else None

    # ----------------------------------------------------------------- forward
    def _p(self, key: str) -> torch.Tensor:
        """Parameter `key` (K, ...) of the members this forward computes."""
        p = self.params[key]
        return p if self._computed is None else p[self._computed]

    def _linear(self, z: torch.Tensor, prefix: str, name: str) -> torch.Tensor:
        w = self._p(_key(f"{prefix}.{name}.weight"))  # (K, out, in)
        b = self._p(_key(f"{prefix}.{name}.bias"))  # (K, out)
        return torch.baddbmm(b.unsqueeze(1), z, w.transpose(1, 2))

    def _activation(self, z: torch.Tensor) -> torch.Tensor:
        if not (self.training and self.dropout > 0):
            return torch.relu(z)
        mask = next(self._step_masks) if self._step_masks is not None else dropout_mask(z, self.dropout)
        return relu_dropout(z, mask, 1.0 / (1.0 - self.dropout))

    def _features(self, x: torch.Tensor) -> torch.Tensor:
        """(K, N, d) raw instances -> (K, N, F) features (through the image encoder first where
        the states hold an image)."""
        shift, scale = ((self.input_shift, self.input_scale) if self._computed is None
                        else (self.input_shift[self._computed], self.input_scale[self._computed]))
        values = self.config.image_values
        z = (x[..., values:].float() - shift[:, None, values:]) / scale[:, None, values:]
        if values:
            e = self._encode(x)
            z = torch.cat([e, z], dim=-1) if z.shape[-1] else e  # (K, N, P*c + v)
        for name in self._fe:
            z = self._activation(self._linear(z, "feature_extractor", name))
        return z

    def _encode(self, x: torch.Tensor) -> torch.Tensor:
        """The image encoder (`image_encoder`) of (K, N, d) raw instances -> (K, N, P*c):
        `image_encoder.PatchLayer` on their patches, which are the image values as they are when
        they come in the encoder's order (`patch_ordered`: a `BagTensors` of `patch_layout`),
        else a copy of them in that order."""
        cfg = self.config
        (h, w, c), p = cfg.image_shape, cfg.patch
        K, N = x.shape[:2]
        pixels = x[..., :cfg.image_values]
        if self._patch_ordered:
            pixels = pixels.reshape(K, N, (h // p) * (w // p), p * p * c)
        else:
            pixels = patches(pixels, cfg.image_shape, p)
        weight, bias = pixel_weights(self._p("encoder__weight"), self._p("encoder__bias"))
        return PatchLayer.apply(pixels, weight, bias).view(K, N, -1)

    def _head_out(self, z: torch.Tensor) -> torch.Tensor:
        """(K, N, in) -> (K, N) in label units."""
        last = len(self._head) - 1
        for i, name in enumerate(self._head):
            z = self._linear(z, "head", name)
            if i < last:
                z = self._activation(z)
        return output_activation(self.config.output_activation, z.squeeze(-1)) * self.return_scale

    def _lstm(self, f: torch.Tensor) -> torch.Tensor:
        """(K, B, T, F) features -> (K, B, T, k) hidden states h'_{t+1}, one LSTM per member."""
        K, B, T, F = f.shape
        k = self.hidden_size
        eye = torch.eye(K, dtype=f.dtype)
        p = {key: self._p(key) for key in ("lstm__weight_ih_l0", "lstm__weight_hh_l0", "lstm__bias_ih_l0",
                                           "lstm__bias_hh_l0", "h0", "c0")}
        # torch's gate-major layout [i | f | g | o], each gate block ordered by member then unit
        w_hh = torch.einsum("mghj,ml->gmhlj", p["lstm__weight_hh_l0"].view(K, 4, k, k), eye)
        b_hh = p["lstm__bias_hh_l0"].view(K, 4, k).transpose(0, 1).reshape(-1)
        if 4 * k < F:
            # Each member's gate inputs W_ih f + b_ih as K small products, fed to the fused LSTM
            # through an identity input weight: (4Kk)^2 per step instead of the block-diagonal
            # (4Kk)(KF), most of which multiplies zeros.
            gates = torch.baddbmm(p["lstm__bias_ih_l0"].unsqueeze(1), f.reshape(K, B * T, F),
                                  p["lstm__weight_ih_l0"].transpose(1, 2))  # (K, B*T, 4k)
            inp = gates.view(K, B, T, 4, k).permute(1, 2, 3, 0, 4).reshape(B, T, 4 * K * k)
            w_ih = torch.eye(4 * K * k, dtype=f.dtype)
            b_ih = torch.zeros(4 * K * k, dtype=f.dtype)
        else:
            w_ih = torch.einsum("mghf,ml->gmhlf", p["lstm__weight_ih_l0"].view(K, 4, k, F), eye)
            w_ih = w_ih.reshape(4 * K * k, K * F)
            b_ih = p["lstm__bias_ih_l0"].view(K, 4, k).transpose(0, 1).reshape(-1)
            inp = f.permute(1, 2, 0, 3).reshape(B, T, K * F)
        h0 = p["h0"].reshape(1, 1, K * k).expand(1, B, K * k).contiguous()
        c0 = p["c0"].reshape(1, 1, K * k).expand(1, B, K * k).contiguous()
        out, _, _ = torch.lstm(inp, (h0, c0), [w_ih, w_hh.reshape(4 * K * k, K * k), b_ih, b_hh],
                               True, 1, 0.0, self.training, False, True)
        return out.view(B, T, K, k).permute(2, 0, 1, 3)

    def _attention(self, f: torch.Tensor) -> torch.Tensor:
        """(K, B, T, F) features -> (K, B, T, k) outputs z_t of each member's causal attention
        (`models.CausalAttention`), as batched products over the members."""
        from .architectures import time_code

        K, B, T, F = f.shape
        k = self.hidden_size
        p = {name: self._p(f"attention__{name}") for name in
             ("inp__weight", "inp__bias", "query__weight", "key__weight", "value__weight", "out__weight", "out__bias")}
        x = torch.baddbmm(p["inp__bias"].unsqueeze(1), f.reshape(K, B * T, F), p["inp__weight"].transpose(1, 2))
        x = (x.view(K, B, T, k) + torch.as_tensor(time_code(T, k), dtype=f.dtype)).reshape(K, B * T, k)
        q, key, v = (torch.bmm(x, p[f"{n}__weight"].transpose(1, 2)).view(K * B, T, k) for n in ("query", "key", "value"))
        scores = (q @ key.transpose(1, 2) / k ** 0.5).masked_fill(torch.ones(T, T, dtype=torch.bool).triu(1),
                                                                 float("-inf"))
        a = (torch.softmax(scores, dim=-1) @ v).view(K, B * T, k)
        z = torch.tanh(x + torch.baddbmm(p["out__bias"].unsqueeze(1), a, p["out__weight"].transpose(1, 2)))
        return z.view(K, B, T, k)

    @property
    def patch_layout(self) -> tuple | None:
        """(image_shape, patch) of the image encoder (None without an image): `BagTensors(ds,
        model.patch_layout)` stores the pixels in the order the encoder reads them, once."""
        cfg = self.config
        return (tuple(cfg.image_shape), int(cfg.patch)) if cfg.image_shape else None

    def forward(self, x: torch.Tensor, lengths: torch.Tensor, members: torch.Tensor | None = None,
                patch_ordered: bool = False) -> MILOutput:
        """members: indices (K',) of the members to compute (None: all); the others cost nothing
        (training leaves out the members that are done). patch_ordered: the image values of x are
        in the encoder's order (a `BagTensors` of `patch_layout`), not as the state holds them."""
        K = self.members if members is None else len(members)
        if x.dim() == 3:
            x = x.unsqueeze(0).expand(K, *x.shape)
        if lengths.dim() == 1:
            lengths = lengths.unsqueeze(0).expand(K, -1)
        self._step_masks, self._computed, self._patch_ordered = None, members, bool(patch_ordered)
        try:
            if self.training and self.dropout_masks is not None:
                # each member's own longest bag: its dropout masks cover only its own instances
                self._step_masks = iter(self.dropout_masks.take(x.shape[1], member_steps(lengths), members))
            return self._forward(x, lengths)
        finally:
            self._step_masks = self._computed = None  # valid for this forward only
            self._patch_ordered = False

    def _forward(self, x: torch.Tensor, lengths: torch.Tensor) -> MILOutput:
        """forward() of (K, B, T, d) instances and (K, B) lengths: features, [LSTM,] head, then
        the architecture's rule (`architectures.REGISTRY`)."""
        K, B, T, d = x.shape
        mask = (torch.arange(T)[None, None, :] < lengths[..., None]).float()  # (K, B, T)
        f = self._features(x.reshape(K, B * T, d))
        hidden = (self._lstm(f.view(K, B, T, -1)) if self.uses_lstm
                  else self._attention(f.view(K, B, T, -1)) if self.uses_attention else None)  # (K, B, T, k)
        flat_hidden = None if hidden is None else hidden.reshape(K, B * T, -1)
        y = self._head_out(self.rule.head_input(f, flat_hidden)).view(K, B, T)
        returns, rewards = self.rule.outputs(y, mask, lengths)
        if hidden is None:
            return MILOutput(returns, rewards, mask.new_zeros(K, B, T, 0))
        return MILOutput(returns, rewards, hidden * mask[..., None])

    def layers(self, member: int | None = None) -> dict:
        """The weights by part, detached: {"feature_extractor": [(W (K, out, in), b (K, out)), ...],
        "head": [...], and with an LSTM "lstm": {"weight_ih" (K, 4k, F), "weight_hh" (K, 4k, k),
        "bias_ih", "bias_hh" (K, 4k), "h0", "c0" (K, k)}} (torch's gate order [i | f | g | o]);
        with attention "attention": {"inp" (K, k, F), "query", "key", "value", "out" (K, k, k),
        "inp_bias", "out_bias" (K, k)}; with an image encoder "encoder": (W (K, c, ppC), b (K, c));
        `member`: that member's only, without the member axis."""
        pick = (lambda t: t.detach()) if member is None else (lambda t: t.detach()[member])
        p = self.params
        out = {part: [(pick(p[_key(f"{part}.{n}.weight")]), pick(p[_key(f"{part}.{n}.bias")]))
                      for n in names]
               for part, names in (("feature_extractor", self._fe), ("head", self._head))}
        if self.config.image_shape:
            out["encoder"] = (pick(p["encoder__weight"]), pick(p["encoder__bias"]))
        if self.uses_attention:
            out["attention"] = {name: pick(p[f"attention__{name}__weight"]) for name in ("inp", "query", "key", "value", "out")}
            out["attention"].update({f"{name}_bias": pick(p[f"attention__{name}__bias"]) for name in ("inp", "out")})
        if self.uses_lstm:
            out["lstm"] = {name: pick(p[key]) for name, key in (
                ("weight_ih", "lstm__weight_ih_l0"), ("weight_hh", "lstm__weight_hh_l0"),
                ("bias_ih", "lstm__bias_ih_l0"), ("bias_hh", "lstm__bias_hh_l0"), ("h0", "h0"), ("c0", "c0"))}
        return out


def member_steps(lengths: torch.Tensor) -> list:
    """Each member's longest bag in a batch of lengths (K, B) (0s for an empty batch)."""
    return lengths.max(dim=1).values.tolist() if lengths.shape[-1] else [0] * lengths.shape[0]


def as_ensemble(model: MILRewardModel | MILEnsemble) -> MILEnsemble:
    """An ensemble of one holding a copy of a `MILRewardModel`'s weights and normalisation;
    anything else (a `MILEnsemble`) is returned as it is (the package computes with ensembles
    only; a single model is K = 1)."""
    if not isinstance(model, MILRewardModel):
        return model
    return MILEnsemble.from_members([model]).train(model.training)


def init_ensemble(config: ModelConfig, seeds: list) -> MILEnsemble:
    """An ensemble whose member m is initialised exactly as `build_model(config)` after
    `torch.manual_seed(seeds[m])` (so a 1-member ensemble starts where a single run starts)."""
    models = []
    for seed in seeds:
        torch.manual_seed(int(seed))
        models.append(build_model(config))
    return MILEnsemble.from_members(models)
