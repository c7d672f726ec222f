"""train.py - trains a small Forge4D (tools/reference/forge4d_ref.py) on venue takes
(gen_data.py) on the CPU, in the paper's stages adapted to exact ground truth:

  stage 1  cameras (pose encoding, every camera-head iteration), depth and points with
           confidence (VGGT's conf-weighted L1 - a log conf), the Gaussian head by a
           rendering loss (L2 + 0.25 (1 - SSIM)) at one input and one held-out camera with
           raster.py, sky opacity, and the scale head by the gauge loss |log g - log g*|;
  stage 2  state tokens on sequences (T keys in order, state carried, base frozen): the
           stage-1 geometry losses at every key; only state.* trains, so the stateless
           model (the shipped GGUF) is exactly stage 1's;
  stage 3  motion blocks and head with the exact per-pixel 3D motion (M1[t], M2[t-1]) and
           a rendering loss at the mid time (Gaussians of t and t-1 moved half way, both
           drawn); keys run with the state carried, as the runtime runs them;
  stage 4  the fusion MLP alone: the interpolated frame at the mid time built exactly as
           firmware/gaussians/interp builds it (pairs by the projected motion, tau 0.05 m,
           occluded Gaussians kept, t-1's matched ones dropped) and rendered at one input
           camera (the model's own metric camera) against the true mid-time image.

Frames and units: the model works in view 0's camera frame; ground truth is moved there
and divided by the scene scale s (mean distance of the valid points of the key to view 0's
centre), VGGT's normalisation. The gauge target is g* = 1 / s: model units per metre, the
factor the runtime divides by (forge4d-arch.md 3), so metric = model / g.

    /usr/bin/python3 tools/train/train.py --stage 1 --minutes 45 [--resume | --init-gguf F]
    /usr/bin/python3 tools/train/train.py --export tools/train/shipped   # safetensors + config

Checkpoints: tools/train/checkpoints/stage{N}.pt (model, optimiser, step, log), written
every --save-every steps and at the end; --resume continues the stage where it stopped.
"""
import argparse
import csv
import json
import math
import os
import random
import struct
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "reference"))
import data  # noqa: E402
import gguf_read  # noqa: E402
import raster  # noqa: E402
from forge4d_ref import Forge4D, average_pairs, fuse_pairs, gaussian_activate  # noqa: E402
from vggt_ref import Config, pose_to_extri_intri  # noqa: E402

SSIM_W = 0.25
CONF_ALPHA = 0.05
# Gaussian scale logits above this (e^1.5 = 4.5 pixel footprints) are clamped while
# training and penalised: one wide Gaussian per pixel covers the whole image, and the
# (sub-tile, Gaussian) pairs of the PyTorch rasterizer then grow without bound.
SCALE_TRAIN_MAX = 1.5

# The shipped model's shape (README: why this size).
SMALL = dict(img_size=112, patch_size=14, embed_dim=96, depth=4, num_heads=4, mlp_ratio=4.0,
             num_register_tokens=4, patch_embed="conv", dino_depth=0, dino_num_heads=1,
             camera_trunk_depth=2, camera_num_heads=4, camera_iters=4, dpt_features=16,
             dpt_out_channels=[16, 32, 48, 48], dpt_layer_idx=[0, 1, 2, 3],
             motion_dpt_features=16)


def make_model(cfgd, stream=True, seed=0):
    torch.manual_seed(seed)
    m = Forge4D(Config(**cfgd), stream=stream)
    # camera head: start near the identity rotation and a 1 rad field of view (the
    # iterations add up, so a quarter per iteration), not at a degenerate quaternion
    fc2 = m.camera_head.pose_branch.fc2
    with torch.no_grad():
        fc2.weight.mul_(0.1)
        fc2.bias.zero_()
        fc2.bias[6] = 1.0 / cfgd["camera_iters"]
        fc2.bias[7:9] = 1.0 / cfgd["camera_iters"]
    return m


# ---------------------------------------------------------------------------
# ground truth in view 0's frame


def mat_to_quat_xyzw(R):
    """R [N,3,3] -> unit quaternion [N,4] (x, y, z, w), w >= 0."""
    w = torch.sqrt(torch.clamp(1 + R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2], min=1e-12)) / 2
    x = torch.sqrt(torch.clamp(1 + R[:, 0, 0] - R[:, 1, 1] - R[:, 2, 2], min=0)) / 2
    y = torch.sqrt(torch.clamp(1 - R[:, 0, 0] + R[:, 1, 1] - R[:, 2, 2], min=0)) / 2
    z = torch.sqrt(torch.clamp(1 - R[:, 0, 0] - R[:, 1, 1] + R[:, 2, 2], min=0)) / 2
    x = torch.copysign(x, R[:, 2, 1] - R[:, 1, 2])
    y = torch.copysign(y, R[:, 0, 2] - R[:, 2, 0])
    z = torch.copysign(z, R[:, 1, 0] - R[:, 0, 1])
    q = torch.stack([x, y, z, w], -1)
    return q / q.norm(dim=-1, keepdim=True)


def to_frame0(w2c0, P):
    """World points / vectors [..., 3] -> view 0's camera frame (R0 p + t0)."""
    return P @ w2c0[:3, :3].T + w2c0[:3, 3]


class Sample:
    """One key of one take with a chosen subset of input views, in view 0's frame."""

    def __init__(self, take, k, views, with_eval=True):
        self.take, self.k, self.views = take, k, views
        w2c = take.w2c[views]
        c2w0 = torch.linalg.inv(w2c[0])
        self.w2c0 = w2c[0]
        self.rel = w2c @ c2w0  # view i in view 0's frame (metric)
        self.K = take.K[views]
        self.images = take.rgb[k][views].permute(0, 3, 1, 2).contiguous()  # [S,3,H,W]
        self.depth = take.depth[k][views]
        self.mask = take.alpha[k][views] > 0.5
        pts = data.unproject(self.depth, self.K, w2c)
        self.points = to_frame0(self.w2c0, pts)  # metres, view 0 frame
        valid = self.points[self.mask]
        self.s = valid.norm(dim=-1).mean().clamp(min=0.1) if valid.numel() else torch.tensor(1.0)
        self.sky = take.sky
        if with_eval and take.E:
            self.eval_rel = take.eval_w2c @ c2w0
            self.eval_K = take.eval_K
            self.eval_rgb = take.eval_rgb[k]

    def pose_enc(self):
        """Ground-truth pose encoding in model units: T / s, quaternion (xyzw), fov h, w."""
        H, W = self.images.shape[2:]
        R, T = self.rel[:, :3, :3], self.rel[:, :3, 3] / self.s
        fy, fx = self.K[:, 1, 1], self.K[:, 0, 0]
        fovh, fovw = 2 * torch.atan(H / (2 * fy)), 2 * torch.atan(W / (2 * fx))
        return torch.cat([T, mat_to_quat_xyzw(R), fovh[:, None], fovw[:, None]], -1)


# ---------------------------------------------------------------------------
# model with gradients (the reference's forward is inference-only)


def run_base(model, images, after_global=None):
    S, _, H, W = images.shape
    layers = model.aggregator(images, {}, after_global)
    poses = model.camera_head(layers[-1])
    ext, K = pose_to_extri_intri(poses[-1], H, W)
    depth, dconf = model.depth_head(layers, H, W, {}, "depth_head")
    pts, pconf = model.point_head(layers, H, W, {}, "point_head")
    raw, _ = model.gaussian_head(layers, H, W, {}, "gaussian_head")
    g = model.scale_head(layers[-1])
    rs = raw[..., 7:10]
    raw_t = torch.cat([raw[..., :7], torch.clamp(rs, max=SCALE_TRAIN_MAX), raw[..., 10:]], -1)
    act = gaussian_activate(raw_t, pts, images, ext, K)
    act["scale_excess"] = F.relu(rs - SCALE_TRAIN_MAX).mean()
    return dict(layers=layers, poses=poses, ext=ext, K=K, depth=depth[..., 0], dconf=dconf, pts=pts,
                pconf=pconf, raw=raw, gauge=g, act=act)


def conf_l1(pred, gt, conf, mask):
    """VGGT's confidence-weighted regression: conf |pred - gt| - alpha log conf (valid px)."""
    if mask.sum() == 0:
        return pred.sum() * 0
    err = (pred - gt).abs()
    if err.dim() == 4:
        err = err.sum(-1)
    return (conf * err)[mask].mean() - CONF_ALPHA * torch.log(conf[mask]).mean()


def camera_loss(poses, gt):
    n, loss = len(poses), 0.0
    for i, p in enumerate(poses):
        w = 0.8 ** (n - 1 - i)
        q, qg = p[:, 3:7], gt[:, 3:7]
        qn = q / q.norm(dim=-1, keepdim=True).clamp(min=1e-6)
        lq = torch.minimum((qn - qg).abs().sum(-1), (qn + qg).abs().sum(-1)).mean()
        loss = loss + w * ((p[:, :3] - gt[:, :3]).abs().sum(-1).mean() + lq + (p[:, 7:] - gt[:, 7:]).abs().sum(-1).mean())
    return loss


def render_view(act, scale, w2c, K, H, W, bg, mask_pts=None):
    """Render the predicted Gaussians (model units x scale = metres) at a camera."""
    mu = act["mu"].reshape(-1, 3) * scale
    sig = act["sigma"].reshape(-1, 3) * scale
    return raster.render(mu, sig, act["rot"].reshape(-1, 4), act["opacity"].reshape(-1),
                         act["rgb"].reshape(-1, 3), w2c, K, W, H, bg=bg)


def image_loss(pred, gt):
    """L2 + 0.25 (1 - SSIM); pred, gt [H,W,3]."""
    return F.mse_loss(pred, gt) + SSIM_W * (1 - raster.ssim(pred.permute(2, 0, 1), gt.permute(2, 0, 1)))


def stage1_losses(model, smp, render=True, n_eval=1):
    out = run_base(model, smp.images)
    s = smp.s
    L = {}
    L["cam"] = camera_loss(out["poses"], smp.pose_enc())
    # depth in each view's own camera (model units), points in view 0's frame
    L["depth"] = conf_l1(out["depth"], smp.depth / s, out["dconf"], smp.mask)
    L["points"] = conf_l1(out["pts"], smp.points / s, out["pconf"], smp.mask)
    # Gaussian centres on the true surface: without it the rendering loss alone drove the
    # offsets dp to metres (Gaussians pushed out of view instead of coloured right)
    L["mu"] = (out["act"]["mu"] - smp.points / s).abs().sum(-1)[smp.mask].mean() if smp.mask.any() else out["pts"].sum() * 0
    L["gauge"] = (torch.log(out["gauge"]) - torch.log(1.0 / s)).abs()
    op = out["act"]["opacity"].clamp(1e-4, 1 - 1e-4)
    L["sky"] = F.binary_cross_entropy(op, smp.mask.float())
    L["scale_reg"] = out["act"]["scale_excess"]
    H, W = smp.images.shape[2:]
    if render:
        i = random.randrange(len(smp.views))
        r = render_view(out["act"], s, smp.rel[i], smp.K[i], H, W, smp.sky)
        L["render_in"] = image_loss(r["rgb"], smp.images[i].permute(1, 2, 0))
        if hasattr(smp, "eval_rel"):
            for e in random.sample(range(smp.eval_rel.shape[0]), min(n_eval, smp.eval_rel.shape[0])):
                r = render_view(out["act"], s, smp.eval_rel[e], smp.eval_K[e], H, W, smp.sky)
                L["render_eval"] = image_loss(r["rgb"], smp.eval_rgb[e])
    W8 = dict(cam=1.0, depth=1.0, points=1.0, mu=1.0, gauge=1.0, sky=0.1, scale_reg=1.0, render_in=4.0, render_eval=4.0)
    total = sum(W8[k] * v for k, v in L.items())
    return total, {k: float(v) for k, v in L.items()}, out


# ---------------------------------------------------------------------------
# stage 2 / 3


def stream_pos(cfg, H, W):
    ns = 1 + cfg.num_register_tokens
    h, w = H // cfg.patch_size, W // cfg.patch_size
    pos = torch.zeros(ns + h * w, 2, dtype=torch.int64)
    rr, cc = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    pos[ns:, 0] = rr.flatten() + 1
    pos[ns:, 1] = cc.flatten() + 1
    return pos


def state_steps(model, take, views, upto):
    """Keys 0..upto in order through the base with the state carried from key 0 (the
    runtime's order): yields (sample, outputs) per key; gradients flow through the state
    unless the caller turns them off."""
    s_prev = [model.state.tokens for _ in range(model.cfg.depth)]
    for k in range(upto + 1):
        smp = Sample(take, k, views, with_eval=False)
        s_new = list(s_prev)

        def after_global(i, x, pos):
            x, s_new[i] = model.state.blocks[i](x, s_prev[i])
            return x

        yield smp, run_base(model, smp.images, after_global)
        s_prev = s_new


def run_state_seq(model, take, views):
    """Stage 2: the keys in order with the state carried (training: gradients through it)."""
    total, logs = 0.0, {}
    for k, (smp, out) in enumerate(state_steps(model, take, views, take.T - 1)):
        s = smp.s
        lk = camera_loss(out["poses"], smp.pose_enc()) + conf_l1(out["depth"], smp.depth / s, out["dconf"], smp.mask) \
            + conf_l1(out["pts"], smp.points / s, out["pconf"], smp.mask) \
            + (torch.log(out["gauge"]) - torch.log(1.0 / s)).abs()
        total = total + lk / take.T
        logs[f"k{k}"] = float(lk)
    return total, logs


@torch.no_grad()
def run_keys(model, take, views, upto):
    """Keys 0..upto through the frozen base with the state carried (what the runtime
    feeds the motion blocks); no gradients."""
    return [out for _, out in state_steps(model, take, views, upto)]


def motion_targets(take, k, views, smp):
    """GT per-pixel motion of key k (to k-1 and k+1), view 0 frame, model units."""
    R0 = smp.w2c0[:3, :3]
    mb = take.motion_bwd[k][views] @ R0.T / smp.s
    mf = take.motion_fwd[k][views] @ R0.T / smp.s
    return mb, mf


def run_motion(model, take, k, views, mid_weight=1.0):
    """Stage 3: keys k-1 and k through the frozen base; M1[k] and M2[k-1] by the motion
    blocks and head; losses against exact motion and the mid-time render."""
    cfg = model.cfg
    a, b = Sample(take, k - 1, views), Sample(take, k, views)
    b.s = a.s  # one scale for the pair: motion vectors in the same units
    outs = run_keys(model, take, views, k)  # state carried from key 0, as the runtime runs
    oa, ob = outs[k - 1], outs[k]
    H, W = a.images.shape[2:]
    pos = stream_pos(cfg, H, W)
    za, zb = model.motion.inputs(oa["layers"]), model.motion.inputs(ob["layers"])
    m1, _ = model.motion_head(model.motion(zb, za, pos), H, W, {}, "motion_head")  # t -> t-1
    m2, _ = model.motion_head(model.motion(za, zb, pos), H, W, {}, "motion_head")  # t-1 -> t
    mb_gt, _ = motion_targets(take, k, views, b)
    _, mf_gt = motion_targets(take, k - 1, views, a)
    L = {}
    L["m1"] = (m1 - mb_gt).abs().sum(-1)[b.mask].mean()
    L["m2"] = (m2 - mf_gt).abs().sum(-1)[a.mask].mean()
    # mid time: both key frames' Gaussians moved half way, drawn together
    if mid_weight and take.mid_rgb is not None and hasattr(a, "eval_rel"):
        i = random.randrange(len(views) + a.eval_rel.shape[0])
        if i < len(views):
            w2c, K, gt = a.rel[i], a.K[i], take.mid_rgb[k - 1][views[i]]
        else:
            e = i - len(views)
            w2c, K, gt = a.eval_rel[e], a.eval_K[e], take.mid_rgb[k - 1][take.V + e]
        acts = []
        for o, m in ((ob["act"], 0.5 * m1), (oa["act"], 0.5 * m2)):
            acts.append({kk: (v + m if kk == "mu" else v) for kk, v in o.items()})
        cat = {kk: torch.cat([acts[0][kk].reshape(-1, acts[0][kk].shape[-1] if acts[0][kk].dim() == 4 else 1),
                              acts[1][kk].reshape(-1, acts[1][kk].shape[-1] if acts[1][kk].dim() == 4 else 1)])
               for kk in ("mu", "sigma", "rot", "rgb", "opacity")}
        cat["opacity"] = cat["opacity"][:, 0]
        r = raster.render(cat["mu"] * a.s, cat["sigma"] * a.s, cat["rot"], cat["opacity"], cat["rgb"], w2c, K, W, H,
                          bg=a.sky)
        L["mid"] = image_loss(r["rgb"], gt)
    # model units are ~3-4 m and a key interval moves a person ~1-5 cm while most pixels
    # (floor, backdrop) stay still: the mean L1 starts near 3e-4, so weight 1000 puts it
    # beside the mid-time image loss (~0.15) instead of under it
    total = 1000.0 * (L["m1"] + L["m2"]) + mid_weight * L.get("mid", 0.0)
    return total, {kk: float(v) for kk, v in L.items()}


# ---------------------------------------------------------------------------
# stage 4: the fusion MLP, through firmware/gaussians/interp's pairing (interp.h)

FUSION_TAU = 0.05  # metres, interp_config_default().tau


def metric_key(o):
    """One key's output in metres as the runtime hands it to interp (/ its own gauge)."""
    g = o["gauge"].reshape(())
    ext = o["ext"].clone()
    ext[:, :, 3] = ext[:, :, 3] / g
    a = o["act"]
    return dict(mu=a["mu"] / g, sigma=a["sigma"] / g, rot=a["rot"], rgb=a["rgb"], opacity=a["opacity"],
                ext=ext, K=o["K"])


def to_attrs(mu, k):
    """interp.c to_attrs: mu | colour | logit(opacity) | log(scale) | q, flattened [N, 14]."""
    op = k["opacity"].reshape(-1).clamp(1e-6, 1 - 1e-6)
    return torch.cat([mu.reshape(-1, 3), k["rgb"].reshape(-1, 3), torch.log(op / (1 - op))[:, None],
                      torch.log(k["sigma"].reshape(-1, 3).clamp(min=1e-12)), k["rot"].reshape(-1, 4)], -1)


def from_attrs(a):
    n = a[:, 10:14].norm(dim=-1, keepdim=True)
    ident = torch.zeros_like(a[:, 10:14])
    ident[:, 0] = 1.0
    rot = torch.where(n > 1e-12, a[:, 10:14] / n.clamp(min=1e-12), ident)
    return a[:, :3], torch.exp(a[:, 7:10]), rot, torch.sigmoid(a[:, 6]), a[:, 3:6]


def partners(mu, motion, other):
    """interp.c partner() for pixel-aligned keys: X' = mu + motion projected into the same
    view with the other key's cameras; -> X' [N,3], partner index [N], found [N]."""
    S, H, W = mu.shape[:3]
    X = mu + motion
    R, T = other["ext"][:, :, :3], other["ext"][:, :, 3]
    q = torch.einsum("sij,shwj->shwi", R, X) + T[:, None, None, :]
    z = q[..., 2]
    zs = torch.where(z > raster.NEAR, z, torch.ones_like(z))
    K = other["K"]
    u = K[:, 0, 0, None, None] * q[..., 0] / zs + K[:, 0, 2, None, None]
    v = K[:, 1, 1, None, None] * q[..., 1] / zs + K[:, 1, 2, None, None]
    ok = (z > raster.NEAR) & (u >= 0) & (v >= 0) & (u < W) & (v < H) & torch.isfinite(X).all(-1)
    sidx = torch.arange(S)[:, None, None].expand(S, H, W)
    idx = (sidx * H + v.clamp(0, H - 1).floor().long()) * W + u.clamp(0, W - 1).floor().long()
    return X.reshape(-1, 3), idx.reshape(-1), ok.reshape(-1)


def interp_fused(model, km, kt, m1, m2, a, fuse=True):
    """Gaussians at t' = t - 1 + a as interp_at (INTERP_FUSED) builds them: occluded ones of
    t and t-1 kept (deformed), matched pairs of t fused with their partner in t-1 (fusion
    MLP, or averaging with fuse=False), t-1's matched ones dropped. -> render inputs."""
    Xt, it, okt = partners(kt["mu"], m1, km)
    Xm, im, okm = partners(km["mu"], m2, kt)
    mum, mut = km["mu"].reshape(-1, 3), kt["mu"].reshape(-1, 3)
    Dt = (Xt - mum[it]).norm(dim=-1)
    Dm = (Xm - mut[im]).norm(dim=-1)
    fz = okt & (Dt <= FUSION_TAU)
    dropm = okm & (Dm <= FUSION_TAU)
    at = to_attrs(kt["mu"] + (1 - a) * m1, kt)
    am = to_attrs(km["mu"] + a * m2, km)
    pa, pm = at[fz], am[it[fz]]
    n = pa.shape[0]
    fused = fuse_pairs(model.fusion, pa, pm, torch.full((n,), a), Dt[fz]) if fuse else average_pairs(pa, pm)
    allv = torch.cat([at[~fz], fused, am[~dropm]])
    return from_attrs(allv), dict(fused=n, kept_t=int((~fz).sum()), kept_tm1=int((~dropm).sum()))


def run_fusion(model, take, k, views, a=0.5):
    """Stage 4: keys k-1 and k (state carried, motion from the trained blocks, all frozen);
    the interpolated frame at the mid time rendered at one input camera (the model's own
    metric camera of key k) against the true mid-time image; only fusion.* trains."""
    cfg = model.cfg
    outs = run_keys(model, take, views, k)
    oa, ob = outs[k - 1], outs[k]
    H, W = take.H, take.W
    with torch.no_grad():
        pos = stream_pos(cfg, H, W)
        za, zb = model.motion.inputs(oa["layers"]), model.motion.inputs(ob["layers"])
        g = ob["gauge"].reshape(())
        m1 = model.motion_head(model.motion(zb, za, pos), H, W, {}, "motion_head")[0] / g
        m2 = model.motion_head(model.motion(za, zb, pos), H, W, {}, "motion_head")[0] / g
    km, kt = metric_key(oa), metric_key(ob)
    (mu, sig, rot, op, rgb), st = interp_fused(model, km, kt, m1, m2, a)
    i = random.randrange(len(views))
    w2c = torch.cat([kt["ext"][i], torch.tensor([[0.0, 0.0, 0.0, 1.0]])])
    r = raster.render(mu, sig, rot, op, rgb, w2c, kt["K"][i], W, H, bg=take.sky)
    L = image_loss(r["rgb"], take.mid_rgb[k - 1][views[i]])
    return L, dict(mid=float(L), **{kk: float(v) for kk, v in st.items()})


# ---------------------------------------------------------------------------
# training loop


def pick_views(take, lo=2, hi=3):
    n = random.randint(lo, min(hi, take.V))
    return sorted(random.sample(range(take.V), n)) if random.random() < 0.5 else random.sample(range(take.V), n)


def trainable(model, stage):
    for n, p in model.named_parameters():
        if stage == 1:
            p.requires_grad_(not n.startswith(("state.", "motion.", "motion_head.", "fusion.")))
        elif stage == 2:
            p.requires_grad_(n.startswith("state."))
        elif stage == 3:
            p.requires_grad_(n.startswith(("motion.", "motion_head.")))
        else:
            p.requires_grad_(n.startswith("fusion."))
    return [p for p in model.parameters() if p.requires_grad]


@torch.no_grad()
def validate(model, takes, n=8):
    """Novel-view PSNR / SSIM at held-out cameras (metric Gaussians / predicted gauge,
    GT cameras in view 0's frame), metric point distance (m, no alignment), gauge error."""
    model.eval()
    ps, ss, pd, ge = [], [], [], []
    for t in takes[:n]:
        views = list(range(min(t.V, 4)))
        smp = Sample(t, 0, views)
        out = run_base(model, smp.images)
        g = out["gauge"]
        H, W = smp.images.shape[2:]
        for e in range(smp.eval_rel.shape[0]):
            try:
                r = render_view(out["act"], 1.0 / g, smp.eval_rel[e], smp.eval_K[e], H, W, smp.sky)
            except raster.PairBudget:
                continue
            ps.append(raster.psnr(r["rgb"].clamp(0, 1), smp.eval_rgb[e]))
            ss.append(float(raster.ssim(r["rgb"].clamp(0, 1).permute(2, 0, 1), smp.eval_rgb[e].permute(2, 0, 1))))
        pd.append(float((out["pts"] / g - smp.points).norm(dim=-1)[smp.mask].mean()))
        ge.append(float((g * smp.s - 1).abs()))
    model.train()
    return dict(psnr=float(np.mean(ps)), ssim=float(np.mean(ss)), point_dist_m=float(np.mean(pd)),
                gauge_rel_err=float(np.mean(ge)))


def ckpt_path(args, stage):
    return os.path.join(args.ckpt_dir, f"stage{stage}.pt")


def train(args):
    torch.set_num_threads(args.threads)
    random.seed(args.seed + args.stage)
    torch.manual_seed(args.seed + args.stage)
    paths = data.list_takes(args.data, "train")
    if args.max_takes:
        paths = paths[: args.max_takes]
    val_paths = data.list_takes(args.data, "val")
    if not paths:
        sys.exit(f"train.py: no takes under {args.data}/train (run gen_data.py)")
    cache = {}

    def take(p):
        if p not in cache:
            cache[p] = data.Take(p)
        return cache[p]

    cfgd = dict(SMALL)
    if args.config:
        with open(args.config) as f:
            cfgd.update(json.load(f))
    model = make_model(cfgd, stream=True, seed=args.seed)
    os.makedirs(args.ckpt_dir, exist_ok=True)
    state = dict(step=0, log=[], elapsed=0.0)
    cp = ckpt_path(args, args.stage)
    prev = ckpt_path(args, args.stage - 1)
    if args.resume and os.path.exists(cp):
        ck = torch.load(cp)
        model.load_state_dict(ck["model"])
        state = ck["state"]
        print(f"resumed stage {args.stage} at step {state['step']}", flush=True)
    elif args.init_gguf:
        # no checkpoint at hand (ignored by git): continue from shipped weights; the
        # optimiser starts afresh (warm-up again), modules the file lacks keep their init
        _, sd = gguf_read.read(args.init_gguf)
        missing, unexpected = model.load_state_dict(sd, strict=False)
        if unexpected:
            sys.exit(f"train.py: {args.init_gguf} has tensors this model lacks: {unexpected[:5]}")
        state["init"] = args.init_gguf
        print(f"stage {args.stage}: initialised from {args.init_gguf} ({len(sd)} tensors, "
              f"{len(missing)} left at init)", flush=True)
    elif args.stage > 1:
        if not os.path.exists(prev):
            sys.exit(f"train.py: stage {args.stage} needs {prev}")
        model.load_state_dict(torch.load(prev)["model"])
    params = trainable(model, args.stage)
    opt = torch.optim.AdamW(params, lr=args.lr, weight_decay=0.01)
    if args.resume and os.path.exists(cp) and "opt" in ck:
        opt.load_state_dict(ck["opt"])
    val_takes = [take(p) for p in val_paths[:8]]
    t_start = time.time() - state["elapsed"]
    budget = args.minutes * 60.0
    logf = open(os.path.join(args.ckpt_dir, f"stage{args.stage}_log.csv"), "a", newline="")
    logw = csv.writer(logf)

    def save():
        state["elapsed"] = time.time() - t_start
        torch.save(dict(model=model.state_dict(), opt=opt.state_dict(), state=state, config=cfgd,
                        stage=args.stage), cp + ".tmp")
        os.replace(cp + ".tmp", cp)

    model.train()
    while time.time() - t_start < budget and (not args.steps or state["step"] < args.steps):
        step = state["step"]
        lr = args.lr * min(1.0, (step + 1) / args.warmup)
        for gp in opt.param_groups:
            gp["lr"] = lr
        t = take(random.choice(paths))
        views = pick_views(t, 2, args.max_views)
        try:
            if args.stage == 1:
                k = random.randrange(t.T)
                render = random.random() < args.render_frac
                loss, logs, _ = stage1_losses(model, Sample(t, k, views), render=render)
            elif args.stage == 2:
                loss, logs = run_state_seq(model, t, views)
            elif args.stage == 3:
                loss, logs = run_motion(model, t, random.randrange(1, t.T), views)
            else:
                loss, logs = run_fusion(model, t, random.randrange(1, t.T), views)
        except raster.PairBudget as e:  # a degenerate render: skip the sample, keep going
            print(f"stage {args.stage} step {step}: skipped ({e})", flush=True)
            continue
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        state["step"] = step + 1
        el = time.time() - t_start
        row = dict(step=step, time_s=round(el, 1), loss=float(loss), **logs)
        state["log"].append(row)
        logw.writerow([step, round(el, 1), float(loss), json.dumps(logs)])
        if step % 10 == 0:
            logf.flush()
            print(f"stage {args.stage} step {step} t {el:.0f}s loss {float(loss):.4f} "
                  + " ".join(f"{k}={v:.4f}" for k, v in logs.items()), flush=True)
        if args.val_every and step % args.val_every == 0 and step and val_takes and args.stage == 1:
            v = validate(model, val_takes)
            state.setdefault("val", []).append(dict(step=step, **v))
            print(f"  val step {step}: {v}", flush=True)
        if step % args.save_every == 0 and step:
            save()
    save()
    if val_takes and args.stage == 1:
        v = validate(model, val_takes)
        state.setdefault("val", []).append(dict(step=state["step"], **v))
        print(f"  val final: {v}", flush=True)
        save()
    logf.close()
    return model, state


# ---------------------------------------------------------------------------
# export


def write_safetensors(path, sd):
    hdr, off, blobs = {}, 0, []
    for k in sorted(sd):
        a = sd[k].detach().to(torch.float32).contiguous().numpy()
        b = a.tobytes()
        hdr[k] = {"dtype": "F32", "shape": list(a.shape), "data_offsets": [off, off + len(b)]}
        off += len(b)
        blobs.append(b)
    h = json.dumps(hdr).encode()
    h += b" " * ((8 - len(h) % 8) % 8)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(h)))
        f.write(h)
        for b in blobs:
            f.write(b)


def export(args):
    """Latest checkpoint -> OUT/forge4d_small.safetensors + config.json for f4d-convert:
    the whole model (VGGT + Gaussian / scale heads, and from stage 2 on the state, motion
    and fusion modules, which f4d-convert knows by name: one GGUF holds everything)."""
    ck = None
    for st in (4, 3, 2, 1):
        p = ckpt_path(args, st)
        if os.path.exists(p):
            ck = torch.load(p)
            break
    if ck is None:
        sys.exit("train.py: no checkpoint to export")
    os.makedirs(args.export, exist_ok=True)
    sd = ck["model"]
    stream = ("state.", "motion.", "motion_head.", "fusion.")
    if ck["stage"] < 2:  # untrained stream modules would claim a motion model that is not there
        sd = {k: v for k, v in sd.items() if not k.startswith(stream)}
    write_safetensors(os.path.join(args.export, "forge4d_small.safetensors"), sd)
    with open(os.path.join(args.export, "config.json"), "w") as f:
        json.dump(ck["config"], f, indent=1)
    ns = sum(1 for k in sd if k.startswith(stream))
    print(f"exported stage {ck['stage']} checkpoint ({len(sd) - ns} base tensors, {ns} stream tensors)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stage", type=int, default=1, choices=(1, 2, 3, 4))
    ap.add_argument("--data", default=os.path.join(HERE, "data"))
    ap.add_argument("--ckpt-dir", default=os.path.join(HERE, "checkpoints"))
    ap.add_argument("--config", help="JSON overriding the model size (default SMALL)")
    ap.add_argument("--minutes", type=float, default=45.0)
    ap.add_argument("--steps", type=int, default=0, help="stop after this many steps (0: time only)")
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--warmup", type=int, default=100)
    ap.add_argument("--threads", type=int, default=1,
                    help="1: under a shared CPU two OpenMP threads ran 10x slower than one")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-views", type=int, default=3)
    ap.add_argument("--max-takes", type=int, default=0)
    ap.add_argument("--render-frac", type=float, default=0.5, help="share of stage-1 steps with rendering loss")
    ap.add_argument("--val-every", type=int, default=200)
    ap.add_argument("--save-every", type=int, default=50)
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--init-gguf", help="start this stage from a GGUF of ours (f32) instead of the previous stage's checkpoint")
    ap.add_argument("--export", help="write the latest checkpoint's weights to this directory and exit")
    args = ap.parse_args()
    if args.export:
        export(args)
    else:
        train(args)


if __name__ == "__main__":
    main()
