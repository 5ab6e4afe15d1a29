"""VPoser v2 (Pavlakos et al. 2019, SMPL-X paper) as a pose prior, with the user's weights.

VPoser's weights are under the SMPL licence, so nothing is shipped and ``human_body_prior``
is not a dependency: this module re-implements the v2 architecture (a small MLP VAE over the
21 body joints' axis-angle) with the same module layout, so a state dict from
``human_body_prior`` loads as is:

* encoder: flatten, BatchNorm1d(63), Linear(63, H), LeakyReLU, BatchNorm1d(H), Dropout,
  Linear(H, H), Linear(H, H), then two heads ``mu`` / ``logvar`` Linear(H, Z);
* decoder: Linear(Z, H), LeakyReLU, Dropout, Linear(H, H), LeakyReLU, Linear(H, 21 * 6),
  then the continuous 6D -> rotation matrix map (Gram-Schmidt).
``H`` (512) and ``Z`` (32) are read from the weights.

How the fit uses it (``VPoserPrior``): we keep optimising the axis-angle pose (so every other
term and the initialisation are unchanged) and add an encoder-based prior per frame,
``0.5 |mu(pose)|^2 + |R(decode(mu(pose))) - R(pose)|_F^2``: the first term is the latent
negative log-likelihood of the pose's code, the second its distance to the decoder's
manifold of plausible poses (a pose VPoser cannot reproduce is implausible). The network
runs in eval mode (BatchNorm running statistics, no dropout), so it is deterministic and
differentiable. Optimising in the latent space instead (SMPLify-X) would restrict the body
to the decoder's manifold, which is too tight for unusual boxing poses.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import roma
import torch
from torch import nn
from torch.nn import functional as F

N_BODY_JOINTS = 21


class _NormalHead(nn.Module):
    def __init__(self, n_in: int, latent_dim: int) -> None:
        super().__init__()
        self.mu = nn.Linear(n_in, latent_dim)
        self.logvar = nn.Linear(n_in, latent_dim)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return self.mu(h)  # only the mean is used by the prior


class _SixDToRotmat(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(n, 6) -> (n, 3, 3): columns b1, b2, b3 from two Gram-Schmidt vectors."""
        m = x.reshape(-1, 3, 2)
        b1 = F.normalize(m[:, :, 0], dim=1)
        b2 = F.normalize(m[:, :, 1] - (b1 * m[:, :, 1]).sum(1, keepdim=True) * b1, dim=-1)
        b3 = torch.linalg.cross(b1, b2, dim=1)
        return torch.stack([b1, b2, b3], dim=-1)


class VPoser(nn.Module):
    """VPoser v2 network (module names as in ``human_body_prior``)."""

    def __init__(self, num_neurons: int = 512, latent_dim: int = 32) -> None:
        super().__init__()
        nf = N_BODY_JOINTS * 3
        self.latent_dim = latent_dim
        self.encoder_net = nn.Sequential(
            nn.Flatten(),
            nn.BatchNorm1d(nf),
            nn.Linear(nf, num_neurons),
            nn.LeakyReLU(),
            nn.BatchNorm1d(num_neurons),
            nn.Dropout(0.1),
            nn.Linear(num_neurons, num_neurons),
            nn.Linear(num_neurons, num_neurons),
            _NormalHead(num_neurons, latent_dim),
        )
        self.decoder_net = nn.Sequential(
            nn.Linear(latent_dim, num_neurons),
            nn.LeakyReLU(),
            nn.Dropout(0.1),
            nn.Linear(num_neurons, num_neurons),
            nn.LeakyReLU(),
            nn.Linear(num_neurons, N_BODY_JOINTS * 6),
            _SixDToRotmat(),
        )

    def encode_mean(self, body_pose_aa: torch.Tensor) -> torch.Tensor:
        """(n, 21, 3) or (n, 63) axis-angle -> (n, latent) mean code."""
        return self.encoder_net(body_pose_aa.reshape(body_pose_aa.shape[0], -1))

    def decode_rotmat(self, z: torch.Tensor) -> torch.Tensor:
        """(n, latent) -> (n, 21, 3, 3) rotation matrices."""
        return self.decoder_net(z).reshape(z.shape[0], N_BODY_JOINTS, 3, 3)


class VPoserPrior:
    """Encoder-based pose prior (see the module docstring); float64, eval mode, frozen."""

    def __init__(self, model: VPoser) -> None:
        self.model = model.double().eval()
        for p in self.model.parameters():
            p.requires_grad_(False)

    def per_frame(self, body_pose_aa: torch.Tensor) -> torch.Tensor:
        """(n, 21, 3) SMPL body pose (joints 1..21, parent-local) -> (n,) prior values."""
        if body_pose_aa.shape[1:] != (N_BODY_JOINTS, 3):
            raise ValueError(f"VPoser prior expects (n, 21, 3) body poses, got {tuple(body_pose_aa.shape)}")
        mu = self.model.encode_mean(body_pose_aa)
        rec = self.model.decode_rotmat(mu)
        R = roma.rotvec_to_rotmat(body_pose_aa)
        return 0.5 * mu.square().sum(-1) + (rec - R).square().sum(dim=(-1, -2, -3))

    def __call__(self, body_pose_aa: torch.Tensor) -> torch.Tensor:
        """Sum over frames of ``per_frame``."""
        return self.per_frame(body_pose_aa).sum()


def _strip(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Keep the ``encoder_net.*`` / ``decoder_net.*`` entries, whatever their prefix
    (``vp_model.`` in Lightning checkpoints, ``module.`` after DataParallel)."""
    out = {}
    for k, v in state.items():
        for part in ("encoder_net.", "decoder_net."):
            i = k.find(part)
            if i >= 0 and (i == 0 or k[i - 1] == "."):
                out[k[i:]] = v
    return out


def load_vposer(path: str | Path) -> VPoserPrior:
    """Load VPoser v2 weights: a ``human_body_prior`` checkpoint (``.ckpt`` with a
    ``state_dict``) or a plain state dict saved with ``torch.save``. Only tensors are
    unpickled (``weights_only=True``). ``ValueError`` naming ``path`` when unreadable."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: VPoser weights not found (FitConfig.vposer_path)")
    try:
        obj = torch.load(p, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError) as e:
        raise ValueError(
            f"{p}: cannot read VPoser weights safely ({e}). If it is a Lightning checkpoint holding "
            "other objects, save its tensors once in your own environment: "
            "torch.save(torch.load(ckpt, weights_only=False)['state_dict'], 'vposer_v2.pt')"
        ) from e
    state = obj.get("state_dict", obj) if isinstance(obj, dict) else None
    if not isinstance(state, dict):
        raise ValueError(
            f"{p}: expected a state dict or a checkpoint with 'state_dict', got {type(obj).__name__}"
        )
    state = _strip(state)
    try:
        hidden, n_in = state["encoder_net.2.weight"].shape
        latent = state["encoder_net.8.mu.weight"].shape[0]
    except KeyError as e:
        raise ValueError(f"{p}: not VPoser v2 weights (missing {e})") from e
    if n_in != N_BODY_JOINTS * 3:
        raise ValueError(f"{p}: VPoser input has {n_in} features, expected {N_BODY_JOINTS * 3}")
    model = VPoser(num_neurons=int(hidden), latent_dim=int(latent))
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise ValueError(f"{p}: VPoser weights do not match the v2 architecture: {e}") from e
    return VPoserPrior(model)
