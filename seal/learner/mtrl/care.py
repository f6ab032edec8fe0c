"""CARE, context-based representations (Sodhani et al., ICML 2021), for one actor or critic.

A context embedding z_tau of the task weighs a mixture of k encoders of the input: attention
alpha = softmax(MLP(z_tau) / temperature) over the encoders, encoding sum_i alpha_i enc_i(x). The
torso reads [encoding, z_tau] and ends in the output layer. Per task is z_tau's table row alone.
The paper's context is a pretrained language model's embedding of the task's description; here,
as in metaworld-algorithms, it is a learned embedding of the task id.

From metaworld-algorithms' nn/care.py (its MLP is nn/base.py's: `depth` ReLU layers `width` wide,
then a Dense to `head_dim` with no activation; CAREConfig in config/nn.py):
- z_tau = MLP(ReLU(table[tau])): a plain (num_tasks, care_embedding) table (its nn.Embed), ReLU,
  then ReLU layers agent.care_encoder_hidden wide and a linear layer back to care_embedding.
- The table's init is an embedding's, not a Dense's: flax's nn.Embed default N(0, 1 / care_embedding)
  under init = "metaworld_algorithms", nn.Embedding's N(0, 1) under "torch".
- The attention is an MLP of z_tau (the same hidden widths) to care_experts logits, divided by
  care_temperature, softmax over the encoders.
- Each encoder is an MLP of x (the same hidden widths) to care_embedding, no activation on its
  output; the k run as one batched matmul a layer (`Dense` with members = k).
- The encoders' outputs are mixed by an einsum with alpha; the torso input is [encoding, z_tau].
- The torso is ReLU layers agent.hidden wide and the output layer (head_bound), no per-task heads.
- z_tau reaches the torso and the attention with its gradient (nothing is detached).
With layer_norm (a critic's agent.critic_layer_norm) a LayerNorm follows each torso hidden layer's
affine map, before its ReLU; none in the context MLP, the attention MLP or the encoders.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from seal.learner.config import AgentConfig
from seal.learner.mtrl.layers import Dense, dense_stack


def _mlp(layers: nn.ModuleList, x: torch.Tensor) -> torch.Tensor:
    """ReLU after every layer but the last."""
    for layer in layers[:-1]:
        x = F.relu(layer(x))
    return layers[-1](x)


class Care(nn.Module):
    """(B, in_dim) inputs and (B,) task ids -> (B, out_dim); see the module docstring."""

    def __init__(
        self,
        in_dim: int,
        out_dim: int,
        num_tasks: int,
        config: AgentConfig,
        layer_norm: bool = False,
    ) -> None:
        super().__init__()
        k, e, enc = config.care_experts, config.care_embedding, config.care_encoder_hidden
        self.temperature = config.care_temperature
        self.table = nn.Parameter(torch.empty(num_tasks, e))
        self.context_mlp = dense_stack((e, *enc, e))
        self.attention_mlp = dense_stack((e, *enc, k))
        self.encoders = dense_stack((in_dim, *enc, e), members=k)
        self.torso = dense_stack((2 * e, *config.hidden))
        self.norms = nn.ModuleList(nn.LayerNorm(o) for o in (config.hidden if layer_norm else ()))
        self.out = Dense(config.hidden[-1], out_dim)

    def reset_parameters(
        self, generator: torch.Generator, init: str, head_bound: float | None
    ) -> None:
        """Draw the table, the context MLP, the attention MLP, the k encoders layer by layer and
        the torso, in that order; the output layer with head_bound."""
        std = 1.0 / math.sqrt(self.table.shape[1]) if init == "metaworld_algorithms" else 1.0
        with torch.no_grad():
            self.table.normal_(0.0, std, generator=generator)
        for layers in (self.context_mlp, self.attention_mlp, self.encoders, self.torso):
            for layer in layers:
                layer.reset_parameters(generator, init)
        for norm in self.norms:
            norm.reset_parameters()
        self.out.reset_parameters(generator, init, head_bound)

    def context(self, task_ids: torch.Tensor) -> torch.Tensor:
        """(B,) -> (B, care_embedding): z_tau."""
        return _mlp(self.context_mlp, F.relu(F.embedding(task_ids, self.table)))

    def attention(self, context: torch.Tensor) -> torch.Tensor:
        """(B, care_embedding) z_tau -> (B, care_experts) weights over the encoders, each row
        summing to 1."""
        return torch.softmax(_mlp(self.attention_mlp, context) / self.temperature, dim=-1)

    def forward(self, x: torch.Tensor, task_ids: torch.Tensor) -> torch.Tensor:
        """(B, in_dim), (B,) -> (B, out_dim)."""
        z = self.context(task_ids)
        encoding = torch.einsum("kbe,bk->be", _mlp(self.encoders, x), self.attention(z))
        h = torch.cat((encoding, z), dim=-1)
        for i, layer in enumerate(self.torso):
            h = layer(h)
            if self.norms:
                h = self.norms[i](h)
            h = F.relu(h)
        return self.out(h)

    def task_parameters(self) -> list[nn.Parameter]:
        """Parameters whose every entry only one task's samples reach: the embedding table."""
        return [self.table]
