"""The real SH basis (degrees 0..4) is orthonormal on the sphere (quadrature on a fine equirect grid)."""

import torch

from frng.render import envmap
from frng.render.sh import sh_basis


def test_basis_orthonormal_up_to_degree_4():
    H, W = 256, 512
    d = envmap.pixel_directions(H, W, dtype=torch.float64)
    w = envmap.pixel_solid_angles(H, W, dtype=torch.float64)
    Y = sh_basis(4, d).reshape(-1, 25)
    gram = (Y * w.reshape(-1, 1)).T @ Y
    assert torch.allclose(gram, torch.eye(25, dtype=torch.float64), atol=2e-3)
