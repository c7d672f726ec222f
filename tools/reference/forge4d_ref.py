"""forge4d_ref.py - Forge4D's own modules (../shared/docs/forge4d-arch.md) on top of
the PyTorch VGGT of vggt_ref.py, with the same parameter names as the C runtime.

Implemented so far (stage 1 of forge4d-arch.md):
  - gaussian_head.*   a DPT head like VGGT's with 14 output channels
                      (dp 3 | dc 3 | o 1 | s 3 | q 4), last conv zero-initialised,
                      activations of forge4d-arch.md 1 (gaussian_activate);
  - scale_head.*      norm (LN D) -> fc1 (D -> C) -> GELU -> fc2 (C -> 1, zero-init)
                      -> exp: the metric gauge p_gauge_hat, one scalar per time step;
  - metric recovery   positions, Gaussian scales and camera translations divided by
                      p_gauge_hat (forge4d-arch.md 3);
  - gauge_from_translations: the paper's training target p_gauge = mean_i |T_i| / |T_hat_i|
                      over views whose translations are not near zero (the C runtime has
                      the same function for calibrated rigs).
State blocks, motion blocks / head and fusion are later work (issue 10).

Choices where forge4d-arch.md leaves a detail open (the C runtime does the same):
  - the scale footprint uses |z| / |f| (z the view depth of X, f = (fx + fy) / 2), so a
    point behind its camera (random or untrained weights) still gets a positive scale;
  - q = (1, 0, 0, 0) + q_raw is normalised when |q| >= 1e-12, else it is the identity.
"""
import torch
import torch.nn as nn
import torch.nn.functional as F

from vggt_ref import VGGT, DPTHead, Config  # noqa: F401

GAUSS_CH = 14            # dp 3 | dc 3 | o 1 | s 3 | q 4
SH_C0 = 0.28209479177387814
OPACITY_BIAS = 4.0
SCALE_LOG_MIN, SCALE_LOG_MAX = -8.0, 4.0
QUAT_EPS = 1e-12
GAUGE_T_EPS = 1e-6       # |T| below this (model units / metres): no ratio from that view


class ScaleHead(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        c = cfg.embed_dim
        self.norm = nn.LayerNorm(2 * c, eps=1e-5)
        self.fc1 = nn.Linear(2 * c, c)
        self.fc2 = nn.Linear(c, 1)
        nn.init.zeros_(self.fc2.weight)
        nn.init.zeros_(self.fc2.bias)

    def forward(self, last):
        """last: aggregator output of the last layer [S, P', D] -> p_gauge_hat (scalar)."""
        c = last[:, 0].mean(dim=0)                    # camera tokens, mean over views
        x = self.fc2(F.gelu(self.fc1(self.norm(c))))  # exact GELU
        return torch.exp(x[0])


def gaussian_activate(raw, world_points, images, extrinsic, intrinsic):
    """forge4d-arch.md 1. raw [S, H, W, 14], world_points [S, H, W, 3], images [S, 3, H, W],
    extrinsic [S, 3, 4], intrinsic [S, 3, 3] -> dict of activated attributes (model units)."""
    dp, dc, o, s, q = raw[..., 0:3], raw[..., 3:6], raw[..., 6:7], raw[..., 7:10], raw[..., 10:14]
    mu = world_points + dp
    rgb = images.permute(0, 2, 3, 1)
    col = torch.clamp(rgb + dc, 0.0, 1.0)
    alpha = torch.sigmoid(o + OPACITY_BIAS)[..., 0]
    R, T = extrinsic[:, :, :3], extrinsic[:, :, 3]
    z = torch.einsum("sk,shwk->shw", R[:, 2], world_points) + T[:, 2][:, None, None]
    f = 0.5 * (intrinsic[:, 0, 0] + intrinsic[:, 1, 1])
    foot = z.abs() / f.abs()[:, None, None]
    sigma = torch.exp(torch.clamp(s, SCALE_LOG_MIN, SCALE_LOG_MAX)) * foot[..., None]
    qq = q.clone()
    qq[..., 0] = qq[..., 0] + 1.0
    n = qq.norm(dim=-1, keepdim=True)
    ident = torch.zeros_like(qq)
    ident[..., 0] = 1.0
    rot = torch.where(n >= QUAT_EPS, qq / torch.clamp(n, min=QUAT_EPS), ident)
    return {"mu": mu, "rgb": col, "sh0": (col - 0.5) / SH_C0, "opacity": alpha,
            "sigma": sigma, "rot": rot}


def metric_recovery(g, act, extrinsic):
    """forge4d-arch.md 3: positions, scales, camera translations / p_gauge_hat."""
    ext = extrinsic.clone()
    ext[:, :, 3] = ext[:, :, 3] / g
    return act["mu"] / g, act["sigma"] / g, ext


def gauge_from_translations(t_true, t_pred, eps=GAUGE_T_EPS):
    """The paper's p_gauge = mean_i |T_i| / |T_hat_i| (T true, metres; T_hat predicted,
    model units) over the views where both norms are >= eps: a camera at the world
    origin (view 0 of VGGT) or a near-zero prediction gives no ratio. None when no
    view qualifies."""
    nt, npd = t_true.norm(dim=-1), t_pred.norm(dim=-1)
    ok = (nt >= eps) & (npd >= eps)
    if not bool(ok.any()):
        return None
    return (nt[ok] / npd[ok]).mean()


class Forge4D(VGGT):
    """VGGT + Forge4D's stage-1 heads. forward() returns VGGT's dict plus the new
    checkpoints (see make_fixtures.py)."""

    def __init__(self, cfg=None):
        super().__init__(cfg)
        self.gaussian_head = DPTHead(self.cfg, GAUSS_CH, "none")
        last = self.gaussian_head.scratch.output_conv2[2]
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        self.scale_head = ScaleHead(self.cfg)

    @torch.no_grad()
    def forward(self, images):
        S, _, H, W = images.shape
        out = super().forward(images)
        layers = [out.get(f"layer{L}") for L in range(self.cfg.depth)]
        raw, _ = self.gaussian_head(layers, H, W, out, "gaussian_head")
        out["gaussian_raw"] = raw
        act = gaussian_activate(raw, out["world_points"], images, out["extrinsic"], out["intrinsic"])
        out["gaussian_head.mu"] = act["mu"]
        out["gaussian_head.sigma"] = act["sigma"]
        g = self.scale_head(out[f"layer{self.cfg.depth - 1}"])
        out["gauge"] = g.reshape(1)
        pos, scale, ext = metric_recovery(g, act, out["extrinsic"])
        out["gaussians_pos"] = pos
        out["gaussians_scale"] = scale
        out["gaussians_rot"] = act["rot"]
        out["gaussians_opacity"] = act["opacity"]
        out["gaussians_rgb"] = act["rgb"]
        out["extrinsic_metric"] = ext
        return out
