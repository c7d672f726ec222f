"""vggt_ref.py - a PyTorch VGGT written from ../shared/docs/vggt.md (inference path).

The parameter names are the released checkpoint's, so a state_dict made here
converts with f4d-convert exactly like the real one. Every size is configurable
(Config below; the defaults are VGGT-1B) so that tiny random-weight models can
serve as parity fixtures for the C port. forward() returns the final outputs and
the intermediate tensors the C tests check (patch embed, the aggregator layers the
heads read, camera iterations, DPT levels and logits).

Run with Debian's interpreter: /usr/bin/python3 (python3-torch, python3-numpy).
"""
import math
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

RESNET_MEAN = (0.485, 0.456, 0.406)
RESNET_STD = (0.229, 0.224, 0.225)
DPT_HIDDEN2 = 32  # output_conv2.0 width: fixed in VGGT


@dataclass
class Config:
    img_size: int = 518
    patch_size: int = 14
    embed_dim: int = 1024
    depth: int = 24
    num_heads: int = 16
    mlp_ratio: float = 4.0
    num_register_tokens: int = 4
    patch_embed: str = "dino"
    dino_depth: int = 24
    dino_num_heads: int = 16
    camera_trunk_depth: int = 4
    camera_num_heads: int = 16
    camera_iters: int = 4
    dpt_features: int = 256
    dpt_out_channels: list = field(default_factory=lambda: [256, 512, 1024, 1024])
    dpt_layer_idx: list = field(default_factory=lambda: [4, 11, 17, 23])
    # Forge4D's motion path (forge4d_ref.py; the C runtime's model.h): aggregator layers
    # with a motion block (None = dpt_layer_idx; list(range(depth)) = forge4d-arch.md 5
    # as written) and the motion head's DPT width (None = dpt_features).
    motion_layers: list = None
    motion_dpt_features: int = 128


# ---------------------------------------------------------------------------
# Blocks


class Attention(nn.Module):
    def __init__(self, dim, heads, qk_norm):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)
        if qk_norm:
            self.q_norm = nn.LayerNorm(dim // heads, eps=1e-5)
            self.k_norm = nn.LayerNorm(dim // heads, eps=1e-5)
        else:
            self.q_norm = None

    def forward(self, x, pos=None):
        n, t, c = x.shape
        d = c // self.heads
        qkv = self.qkv(x).reshape(n, t, 3, self.heads, d).permute(2, 0, 3, 1, 4)
        q, k, v = qkv[0], qkv[1], qkv[2]  # [n, heads, t, d]
        if self.q_norm is not None:
            q = self.q_norm(q)
            k = self.k_norm(k)
        if pos is not None:
            q = rope2d(q, pos)
            k = rope2d(k, pos)
        a = torch.softmax((q @ k.transpose(-1, -2)) * d ** -0.5, dim=-1)
        o = (a @ v).transpose(1, 2).reshape(n, t, c)
        return self.proj(o)


class Mlp(nn.Module):
    def __init__(self, dim, hidden):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x):
        return self.fc2(F.gelu(self.fc1(x)))


class LayerScale(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.gamma = nn.Parameter(torch.ones(dim))

    def forward(self, x):
        return x * self.gamma


class Block(nn.Module):
    def __init__(self, dim, heads, mlp_ratio, eps, qk_norm):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=eps)
        self.attn = Attention(dim, heads, qk_norm)
        self.ls1 = LayerScale(dim)
        self.norm2 = nn.LayerNorm(dim, eps=eps)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.ls2 = LayerScale(dim)

    def forward(self, x, pos=None):
        x = x + self.ls1(self.attn(self.norm1(x), pos))
        return x + self.ls2(self.mlp(self.norm2(x)))


def rope2d(t, pos):
    """vggt.md 4a: y rotates the first half of each head vector, x the second;
    rotate-half inside each half; base 100; angles in float32."""
    d = t.shape[-1]
    m = d // 2
    inv = 1.0 / (100.0 ** (torch.arange(0, m, 2, dtype=torch.float32) / m))
    out = []
    for axis, half in ((0, t[..., :m]), (1, t[..., m:])):
        ang = pos[..., axis].to(torch.float32)[..., None] * inv  # [.., T, m/2]
        ang = torch.cat([ang, ang], dim=-1)
        cos = ang.cos().to(t.dtype)[:, None]
        sin = ang.sin().to(t.dtype)[:, None]
        rot = torch.cat([-half[..., m // 2:], half[..., : m // 2]], dim=-1)
        out.append(half * cos + rot * sin)
    return torch.cat(out, dim=-1)


# ---------------------------------------------------------------------------
# Antialiased bicubic (PIL style), vggt.md 2


def aa_bicubic_weights(n_in, n_out):
    s = n_in / n_out
    support = 2.0 * s if s >= 1 else 2.0
    inv = 1.0 / s if s >= 1 else 1.0
    a = -0.5

    def k(t):
        t = abs(t)
        if t < 1:
            return ((a + 2) * t - (a + 3)) * t * t + 1
        if t < 2:
            return a * (t ** 3 - 5 * t * t + 8 * t - 4)
        return 0.0

    m = np.zeros((n_out, n_in))
    for i in range(n_out):
        center = s * (i + 0.5)
        lo = max(int(math.floor(center - support + 0.5)), 0)
        hi = min(int(math.floor(center + support + 0.5)), n_in)
        w = np.array([k((j - center + 0.5) * inv) for j in range(lo, hi)])
        m[i, lo:hi] = w / w.sum()
    return m


def aa_bicubic(grid, h, w):
    """grid [gh, gw, C] -> [h, w, C]; identity per axis when sizes match."""
    gh, gw = grid.shape[:2]
    my = torch.eye(gh, dtype=grid.dtype) if gh == h else torch.tensor(aa_bicubic_weights(gh, h), dtype=grid.dtype)
    mx = torch.eye(gw, dtype=grid.dtype) if gw == w else torch.tensor(aa_bicubic_weights(gw, w), dtype=grid.dtype)
    return torch.einsum("yi,xj,ijc->yxc", my, mx, grid)


# ---------------------------------------------------------------------------
# Aggregator


class PatchConv(nn.Module):
    def __init__(self, c, p):
        super().__init__()
        self.proj = nn.Conv2d(3, c, p, p)


class DinoViT(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        c, p = cfg.embed_dim, cfg.patch_size
        g = cfg.img_size // p
        self.patch_embed = PatchConv(c, p)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, c))
        self.pos_embed = nn.Parameter(torch.zeros(1, 1 + g * g, c))
        self.register_tokens = nn.Parameter(torch.zeros(1, cfg.num_register_tokens, c))
        self.mask_token = nn.Parameter(torch.zeros(1, c))
        self.blocks = nn.ModuleList(
            [Block(c, cfg.dino_num_heads, cfg.mlp_ratio, 1e-6, False) for _ in range(cfg.dino_depth)])
        self.norm = nn.LayerNorm(c, eps=1e-6)
        self.g = g
        self.r = cfg.num_register_tokens

    def forward(self, x):
        n, _, H, W = x.shape
        x = self.patch_embed.proj(x)  # [n, C, h, w]
        h, w = x.shape[2:]
        x = x.flatten(2).transpose(1, 2)
        x = torch.cat([self.cls_token.expand(n, -1, -1), x], dim=1)
        pe = self.pos_embed
        if not (h * w == self.g * self.g and H == W):
            grid = pe[0, 1:].reshape(self.g, self.g, -1)
            grid = aa_bicubic(grid, h, w).reshape(1, h * w, -1)
            pe = torch.cat([pe[:, :1], grid], dim=1)
        x = x + pe
        x = torch.cat([x[:, :1], self.register_tokens.expand(n, -1, -1), x[:, 1:]], dim=1)
        for b in self.blocks:
            x = b(x)
        return self.norm(x)[:, 1 + self.r:]

    def forward_kept(self, x, kept):
        """Only the kept patches (index lists per view, raster order) run: each
        with its own pos-embed cell, attending within the kept set. Returns a
        list of [len(kept[f]), C]."""
        n, _, H, W = x.shape
        y = self.patch_embed.proj(x)
        h, w = y.shape[2:]
        y = y.flatten(2).transpose(1, 2)
        y = torch.cat([self.cls_token.expand(n, -1, -1), y], dim=1)
        pe = self.pos_embed
        if not (h * w == self.g * self.g and H == W):
            grid = pe[0, 1:].reshape(self.g, self.g, -1)
            grid = aa_bicubic(grid, h, w).reshape(1, h * w, -1)
            pe = torch.cat([pe[:, :1], grid], dim=1)
        y = y + pe
        outs = []
        for f in range(n):
            idx = torch.cat([torch.zeros(1, dtype=torch.long), 1 + torch.as_tensor(kept[f], dtype=torch.long)])
            t = y[f:f + 1, idx]
            t = torch.cat([t[:, :1], self.register_tokens, t[:, 1:]], dim=1)
            for b in self.blocks:
                t = b(t)
            outs.append(self.norm(t)[0, 1 + self.r:])
        return outs


class Aggregator(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        c = cfg.embed_dim
        self.cfg = cfg
        self.patch_embed = DinoViT(cfg) if cfg.patch_embed == "dino" else PatchConv(c, cfg.patch_size)
        self.camera_token = nn.Parameter(torch.zeros(1, 2, 1, c))
        self.register_token = nn.Parameter(torch.zeros(1, 2, cfg.num_register_tokens, c))
        mk = lambda: nn.ModuleList(
            [Block(c, cfg.num_heads, cfg.mlp_ratio, 1e-5, True) for _ in range(cfg.depth)])
        self.frame_blocks = mk()
        self.global_blocks = mk()

    def forward(self, images, out, after_global=None):
        """after_global(i, x [S*P', C], pos [P', 2]) -> x: a callback after global block i
        (Forge4D's state blocks), None for VGGT."""
        S, _, H, W = images.shape
        p = self.cfg.patch_size
        h, w = H // p, W // p
        mean = torch.tensor(RESNET_MEAN, dtype=images.dtype).view(1, 3, 1, 1)
        std = torch.tensor(RESNET_STD, dtype=images.dtype).view(1, 3, 1, 1)
        x = (images - mean) / std
        if self.cfg.patch_embed == "dino":
            pt = self.patch_embed(x)
        else:
            pt = self.patch_embed.proj(x).flatten(2).transpose(1, 2)
        out["patch_embed"] = pt
        cam = torch.cat([self.camera_token[:, :1], self.camera_token[:, 1:].expand(1, S - 1, -1, -1)], dim=1)[0]
        reg = torch.cat([self.register_token[:, :1], self.register_token[:, 1:].expand(1, S - 1, -1, -1)], dim=1)[0]
        tok = torch.cat([cam, reg, pt], dim=1)  # [S, P', C]
        ns = 1 + self.cfg.num_register_tokens
        P1, C = tok.shape[1], tok.shape[2]
        pos = torch.zeros(P1, 2, dtype=torch.int64)
        rr, cc = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
        pos[ns:, 0] = rr.flatten() + 1
        pos[ns:, 1] = cc.flatten() + 1
        layers = []
        for i in range(self.cfg.depth):
            tok = self.frame_blocks[i](tok, pos[None].expand(S, -1, -1))
            fr = tok
            tok = self.global_blocks[i](tok.reshape(1, S * P1, C), pos.repeat(S, 1)[None]).reshape(S, P1, C)
            if after_global is not None:
                tok = after_global(i, tok.reshape(S * P1, C), pos).reshape(S, P1, C)
            layers.append(torch.cat([fr, tok], dim=-1))
        return layers


    def forward_kept(self, images, kept, after_global=None):
        """Foreground-only aggregator: view f runs its special tokens and the
        patches kept[f] (raster indices), with their real RoPE positions;
        frame attention within each view's kept set, global attention over
        all kept tokens. Returns per layer a list over views of
        [ns + len(kept[f]), 2C] (specials first). after_global(i, x, pos)
        -> x sees the packed kept tokens of every view [sum, C] (Forge4D's
        state blocks on a masked step)."""
        S, _, H, W = images.shape
        p = self.cfg.patch_size
        w = W // p
        mean = torch.tensor(RESNET_MEAN, dtype=images.dtype).view(1, 3, 1, 1)
        std = torch.tensor(RESNET_STD, dtype=images.dtype).view(1, 3, 1, 1)
        x = (images - mean) / std
        if self.cfg.patch_embed == "dino":
            pts = self.patch_embed.forward_kept(x, kept)
        else:
            full = self.patch_embed.proj(x).flatten(2).transpose(1, 2)
            pts = [full[f, torch.as_tensor(kept[f], dtype=torch.long)] for f in range(S)]
        ns = 1 + self.cfg.num_register_tokens
        toks, poss = [], []
        for f in range(S):
            slot = 0 if f == 0 else 1
            toks.append(torch.cat([self.camera_token[0, slot], self.register_token[0, slot], pts[f]], dim=0))
            kf = torch.as_tensor(kept[f], dtype=torch.long)
            pos = torch.zeros(ns + len(kept[f]), 2, dtype=torch.int64)
            pos[ns:, 0] = kf // w + 1
            pos[ns:, 1] = kf % w + 1
            poss.append(pos)
        lens = [t.shape[0] for t in toks]
        layers = []
        for i in range(self.cfg.depth):
            toks = [self.frame_blocks[i](t[None], pos[None])[0] for t, pos in zip(toks, poss)]
            fr = toks
            g = self.global_blocks[i](torch.cat(toks)[None], torch.cat(poss)[None])[0]
            if after_global is not None:
                g = after_global(i, g, torch.cat(poss))
            toks = list(torch.split(g, lens))
            layers.append([torch.cat([a, b], dim=-1) for a, b in zip(fr, toks)])
        return layers


# ---------------------------------------------------------------------------
# Camera head


class CameraHead(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        d = 2 * cfg.embed_dim
        self.iters = cfg.camera_iters
        self.token_norm = nn.LayerNorm(d, eps=1e-5)
        self.trunk_norm = nn.LayerNorm(d, eps=1e-5)
        self.empty_pose_tokens = nn.Parameter(torch.zeros(1, 1, 9))
        self.embed_pose = nn.Linear(9, d)
        self.poseLN_modulation = nn.Sequential(nn.SiLU(), nn.Linear(d, 3 * d))
        self.trunk = nn.Sequential(
            *[Block(d, cfg.camera_num_heads, cfg.mlp_ratio, 1e-5, False) for _ in range(cfg.camera_trunk_depth)])
        self.pose_branch = Mlp(d, d // 2)
        self.pose_branch.fc2 = nn.Linear(d // 2, 9)

    def forward(self, last):
        S, _, d = last.shape
        t = self.token_norm(last[:, 0])[None]  # [1, S, D]
        pred = None
        outs = []
        for _ in range(self.iters):
            e = self.embed_pose(self.empty_pose_tokens.expand(1, S, 9) if pred is None else pred)
            shift, scale, gate = self.poseLN_modulation(e).chunk(3, dim=-1)
            x = gate * (F.layer_norm(t, (d,), eps=1e-6) * (1 + scale) + shift) + t
            x = self.trunk(x)
            delta = self.pose_branch(self.trunk_norm(x))
            pred = delta if pred is None else pred + delta
            outs.append(torch.cat([pred[..., :7], F.relu(pred[..., 7:])], dim=-1)[0])
        return outs


def pose_to_extri_intri(enc, H, W):
    S = enc.shape[0]
    T, q = enc[:, :3], enc[:, 3:7]
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    s = 2.0 / (q * q).sum(-1)
    R = torch.stack([
        1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w),
        s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w),
        s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)], -1).reshape(S, 3, 3)
    ext = torch.cat([R, T[:, :, None]], dim=-1)
    fy = (H / 2) / torch.tan(enc[:, 7] / 2)
    fx = (W / 2) / torch.tan(enc[:, 8] / 2)
    K = torch.zeros(S, 3, 3, dtype=enc.dtype)
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = fx, fy, W / 2, H / 2, 1
    return ext, K


# ---------------------------------------------------------------------------
# DPT head


def uv_pos_embed(cx, h, w, W, H):
    """vggt.md 6 PE(cx, h, w): [cx, h, w], frequencies in float64."""
    a = W / H
    sx, sy = a / math.sqrt(a * a + 1), 1 / math.sqrt(a * a + 1)
    u = torch.linspace(-sx * (w - 1) / w, sx * (w - 1) / w, w, dtype=torch.float64)
    v = torch.linspace(-sy * (h - 1) / h, sy * (h - 1) / h, h, dtype=torch.float64)
    K = cx // 4
    om = 1.0 / 100.0 ** (torch.arange(K, dtype=torch.float64) / K)
    uu = u[None, :, None].expand(h, w, 1) * om
    vv = v[:, None, None].expand(h, w, 1) * om
    pe = torch.cat([uu.sin(), uu.cos(), vv.sin(), vv.cos()], dim=-1)  # [h, w, cx]
    return pe.permute(2, 0, 1)


class RCU(nn.Module):
    def __init__(self, f):
        super().__init__()
        self.conv1 = nn.Conv2d(f, f, 3, 1, 1)
        self.conv2 = nn.Conv2d(f, f, 3, 1, 1)

    def forward(self, x):
        x = F.relu(x)  # the in-place ReLU quirk: the skip adds relu(x)
        return x + self.conv2(F.relu(self.conv1(x)))


class Fusion(nn.Module):
    def __init__(self, f, has_rcu1):
        super().__init__()
        if has_rcu1:
            self.resConfUnit1 = RCU(f)
        self.resConfUnit2 = RCU(f)
        self.out_conv = nn.Conv2d(f, f, 1)

    def forward(self, x, skip=None, size=None):
        if skip is not None:
            x = x + self.resConfUnit1(skip)
        x = self.resConfUnit2(x)
        x = F.interpolate(x, size=size, mode="bilinear", align_corners=True)
        return self.out_conv(x)


class Scratch(nn.Module):
    pass


class DPTHead(nn.Module):
    def __init__(self, cfg, output_dim, activation, in_dim=None):
        super().__init__()
        d = in_dim or 2 * cfg.embed_dim  # Forge4D's motion head reads C-wide tokens
        f, oc = cfg.dpt_features, cfg.dpt_out_channels
        self.cfg, self.activation = cfg, activation
        self.norm = nn.LayerNorm(d, eps=1e-5)
        self.projects = nn.ModuleList([nn.Conv2d(d, o, 1) for o in oc])
        self.resize_layers = nn.ModuleList([
            nn.ConvTranspose2d(oc[0], oc[0], 4, 4), nn.ConvTranspose2d(oc[1], oc[1], 2, 2),
            nn.Identity(), nn.Conv2d(oc[3], oc[3], 3, 2, 1)])
        s = Scratch()
        for i in range(4):
            setattr(s, f"layer{i + 1}_rn", nn.Conv2d(oc[i], f, 3, 1, 1, bias=False))
        for i in range(4):
            setattr(s, f"refinenet{i + 1}", Fusion(f, i != 3))
        s.output_conv1 = nn.Conv2d(f, f // 2, 3, 1, 1)
        s.output_conv2 = nn.Sequential(nn.Conv2d(f // 2, DPT_HIDDEN2, 3, 1, 1), nn.ReLU(),
                                       nn.Conv2d(DPT_HIDDEN2, output_dim, 1))
        self.scratch = s

    def forward(self, layers, H, W, out, name):
        p = self.cfg.patch_size
        h, w = H // p, W // p
        ns = 1 + self.cfg.num_register_tokens
        lv = []
        for i, L in enumerate(self.cfg.dpt_layer_idx):
            x = self.norm(layers[L][:, ns:])  # [S, P, D]
            x = x.transpose(1, 2).reshape(x.shape[0], -1, h, w)
            x = self.projects[i](x)
            x = x + 0.1 * uv_pos_embed(x.shape[1], h, w, W, H).to(x.dtype)
            x = self.resize_layers[i](x)
            out[f"{name}.level{i}"] = x
            lv.append(x)
        sc = self.scratch
        rn = [getattr(sc, f"layer{i + 1}_rn")(lv[i]) for i in range(4)]
        y = sc.refinenet4(rn[3], None, rn[2].shape[2:])
        y = sc.refinenet3(y, rn[2], rn[1].shape[2:])
        y = sc.refinenet2(y, rn[1], rn[0].shape[2:])
        y = sc.refinenet1(y, rn[0], (2 * rn[0].shape[2], 2 * rn[0].shape[3]))
        out[f"{name}.fused"] = y
        y = sc.output_conv1(y)
        y = F.interpolate(y, size=(H, W), mode="bilinear", align_corners=True)
        y = y + 0.1 * uv_pos_embed(y.shape[1], H, W, W, H).to(y.dtype)
        y = sc.output_conv2(y)
        out[f"{name}.logits"] = y
        y = y.permute(0, 2, 3, 1)  # [S, H, W, out]
        if self.activation == "none":  # raw channels (the Gaussian head)
            return y, None
        conf = 1 + torch.exp(y[..., -1])
        v = y[..., :-1]
        if self.activation == "exp":
            v = torch.exp(v)
        else:
            v = torch.sign(v) * torch.expm1(torch.abs(v))
        return v, conf


class VGGT(nn.Module):
    def __init__(self, cfg=None):
        super().__init__()
        cfg = cfg or Config()
        self.cfg = cfg
        self.aggregator = Aggregator(cfg)
        self.camera_head = CameraHead(cfg)
        self.point_head = DPTHead(cfg, 4, "inv_log")
        self.depth_head = DPTHead(cfg, 2, "exp")

    @torch.no_grad()
    def forward(self, images, after_global=None):
        """images [S, 3, H, W] in [0, 1] -> dict of outputs and intermediates
        (all aggregator layers under "_layers" when after_global is given)."""
        S, _, H, W = images.shape
        out = {}
        layers = self.aggregator(images, out, after_global)
        if after_global is not None:
            out["_layers"] = layers
        for L in sorted(set(self.cfg.dpt_layer_idx) | {self.cfg.depth - 1}):
            out[f"layer{L}"] = layers[L]
        poses = self.camera_head(layers[-1])
        out["pose_enc_list"] = torch.stack(poses)
        out["pose_enc"] = poses[-1]
        out["extrinsic"], out["intrinsic"] = pose_to_extri_intri(poses[-1], H, W)
        out["depth"], out["depth_conf"] = self.depth_head(layers, H, W, out, "depth_head")
        out["world_points"], out["world_points_conf"] = self.point_head(layers, H, W, out, "point_head")
        return out

    @torch.no_grad()
    def forward_masked(self, images, keep, prev_layers):
        """Foreground-only Eval (model_eval_masked): keep [S, P] bool; the
        kept tokens run (Aggregator.forward_kept), every dropped patch's
        layer rows are prev_layers' (the previous Eval's), then the heads run
        on the full composed layers."""
        S, _, H, W = images.shape
        ns = 1 + self.cfg.num_register_tokens
        kept = [torch.nonzero(keep[f]).flatten().tolist() for f in range(S)]
        packed = self.aggregator.forward_kept(images, kept)
        layers = []
        for L in range(self.cfg.depth):
            comp = prev_layers[L].clone()
            for f in range(S):
                rows = list(range(ns)) + [ns + k for k in kept[f]]
                comp[f, rows] = packed[L][f]
            layers.append(comp)
        out = {}
        for L in sorted(set(self.cfg.dpt_layer_idx) | {self.cfg.depth - 1}):
            out[f"layer{L}"] = layers[L]
        poses = self.camera_head(layers[-1])
        out["pose_enc"] = poses[-1]
        out["depth"], out["depth_conf"] = self.depth_head(layers, H, W, out, "depth_head")
        out["world_points"], out["world_points_conf"] = self.point_head(layers, H, W, out, "point_head")
        return out
