"""DDPM noise schedule and DDIM sampling with x0 prediction (RelitLRM's set-up, notes/relitlrm.md section 2).

- 1000 training steps, betas rising linearly from 0.00085 to 0.012 (plain linear; RelitLRM leaves
  linear vs scaled-linear unspecified).
- The network predicts x0 directly (the rendering of its Gaussians *is* x0-hat); DDIM (eta = 0) turns
  x0-hat into the next, less noisy sample.
- Images are diffused in [-1, 1]: :func:`to_diffusion_space` maps linear RGB through a 1/2.2 gamma
  (RelitLRM also gamma-encodes its targets) so that dark regions get their share of the noise budget.
"""

from __future__ import annotations

import torch

GAMMA = 2.2


def to_diffusion_space(linear_rgb: torch.Tensor) -> torch.Tensor:
    """Linear RGB (...) -> [-1, 1] (clipped to [0, 1] first, then gamma 1/2.2)."""
    return 2.0 * linear_rgb.clamp(0.0, 1.0).pow(1.0 / GAMMA) - 1.0


def from_diffusion_space(x: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`to_diffusion_space` (on the clipped range)."""
    return ((x.clamp(-1.0, 1.0) + 1.0) / 2.0).pow(GAMMA)


class NoiseSchedule:
    """Linear-beta DDPM schedule. ``alpha_bar[t]`` for integer t in [0, steps)."""

    def __init__(self, steps: int = 1000, beta_start: float = 0.00085, beta_end: float = 0.012):
        self.steps = steps
        betas = torch.linspace(beta_start, beta_end, steps, dtype=torch.float64)
        self.alpha_bar = torch.cumprod(1.0 - betas, dim=0).float()

    def _ab(self, t: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        ab = self.alpha_bar.to(like.device)[t.long()]
        return ab.reshape(ab.shape + (1,) * (like.dim() - ab.dim()))

    def q_sample(self, x0: torch.Tensor, t: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """Noise clean samples x0 (B, ...) to timesteps t (B,)."""
        ab = self._ab(t, x0)
        return ab.sqrt() * x0 + (1.0 - ab).sqrt() * noise

    def ddim_timesteps(self, n: int) -> list[int]:
        """n evenly spaced timesteps, descending, starting at the last step (e.g. 5 -> [999, 799, 599, 399, 199])."""
        if n < 1:
            raise ValueError("need at least one denoising step")
        stride = self.steps / n
        return [int(round(self.steps - 1 - i * stride)) for i in range(n)]

    def ddim_step(self, x_t: torch.Tensor, x0_hat: torch.Tensor, t: int, t_prev: int | None) -> torch.Tensor:
        """Deterministic DDIM update from t to t_prev (None = the end: return x0_hat)."""
        if t_prev is None or t_prev < 0:
            return x0_hat
        ab_t = self.alpha_bar[t].item()
        ab_prev = self.alpha_bar[t_prev].item()
        eps = (x_t - ab_t**0.5 * x0_hat) / max(1.0 - ab_t, 1e-8) ** 0.5
        return ab_prev**0.5 * x0_hat + (1.0 - ab_prev) ** 0.5 * eps
