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
Stages 2-3 (forge4d-arch.md 4-6), built with Forge4D(cfg, stream=True) and run one time
step at a time by Forge4D.step(images, stream) (stream = Forge4D.new_stream()):
  - state.tokens [16, C]      the state of every layer at t = 0;
  - state.blocks.{l}.*        after global block l, on x [S*P', C] (all views) and s_l:
        norm_x, norm_s, attn_r.{q, kv, proj}, ls_r.gamma      read:
            x  = x + ls_r * Attn_r(q = norm_x(x), kv = norm_s(s_l))
        norm_s2, norm_x2, attn_w.{q, kv, proj}, ls_w.gamma    write (on the x after the read):
            s' = s_l + ls_w * Attn_w(q = norm_s2(s_l), kv = norm_x2(x))
        norm_m, mlp.{fc1, fc2}, ls_m.gamma
            s' = s' + ls_m * MLP(norm_m(s'))          s' is s_l of the next step;
  - motion layers             cfg.motion_layers (None: dpt_layer_idx), which must contain
                              dpt_layer_idx; forge4d-arch.md 5 as written has every layer
                              (motion_layers = list(range(depth))). The default cuts a
                              motion step to the paper's measured 27 % of a key frame or less;
  - motion.in_proj.{l}        Linear D -> C: z_l(t) = in_proj_l(F_l(t)) on all P' tokens,
                              l in the motion layers (names keep the aggregator index);
  - motion.blocks.{l}.*       norm1, norm_kv, attn.{q, kv, proj}, ls1.gamma, norm2,
                              mlp.{fc1, fc2}, ls2.gamma; per view, h = z_l0 (q side, l0 the
                              first motion layer), then for the motion layers in order
            h = h + zq_l (l > l0)
            h = h + ls1 * CrossAttn(q = norm1(h), kv = norm_kv(zk_l))   2-D RoPE on q, k
            h = h + ls2 * MLP(norm2(h))
        M1[t] runs zq = z(t), zk = z(t-1); M2[t-1] runs zq = z(t-1), zk = z(t), same weights;
        masked step (Forge4D.step_masked, model_eval_masked): see MASKED STEP below;
  - motion_head.*             a DPT head (vggt_ref.DPTHead, input width C, features
                              cfg.motion_dpt_features, None = dpt_features) reading h after
                              the blocks of dpt_layer_idx, 3 raw output channels;
  - fusion.fc1 (30 -> 64), fusion.fc2 (64 -> 14): fuse_pairs().
Cross-attention (CrossAttention): q Linear C -> C, kv Linear C -> 2C (k = the first C
outputs, v the next C, head-major, d contiguous per head), proj Linear C -> C;
num_heads heads of C / num_heads (C/64 = 16 in VGGT-1B), no qk-norm; RoPE only in the
motion blocks. Every LayerNorm of these modules has eps 1e-5; MLP hidden width
int(C * mlp_ratio), exact GELU. LayerScales and the last layers (motion_head's
output_conv2.2, fusion.fc2) are zero-initialised: untrained, state blocks are the identity,
motion is 0 and fusion is averaging.

Order inside one step (the C runtime does the same):
  1. aggregator, state block l right after global block l (read with s_l(t-1), write);
  2. VGGT heads, scale head (gauge g(t)), Gaussian head;
  3. z_l(t) for every motion layer; with a previous step of the same S x H x W: M1[t], M2[t-1]
     in model units, metric = / g(t) (this step's gauge for both);
  4. z(t) is kept (not recomputed) as the next step's z(t-1).

MASKED STEP (step_masked(images, keep, stream); the C runtime does the same): only the
kept patches (keep [S, P]) and every view's special tokens run the aggregator (vggt_ref
Aggregator.forward_kept), packed over the views. State block l reads into the kept rows
only and writes from the kept tokens only (the state learns from what ran, the
foreground). Motion: z_l(t) of a kept row is in_proj_l of its new layer row, of a dropped
row it is z_l(t-1) (the dropped row's layer row is the reused one, so this is in_proj of
it); both runs take queries from the kept rows of this step only (M1: z(t) rows, M2: z(t-1)
rows at the same places; keys / values over the full grid of the other time, RoPE at the
real grid cells). Motion stream rows of dropped patches keep the last step's (like the
layer rows), so the motion head runs on a full grid; then M1 and M2 are set to exactly 0
at every pixel of a dropped patch: a dropped patch is background, static by the mask's
definition. Why one kept set for both runs: M2[t-1] moves t-1's Gaussians; a patch that
held foreground at t-1 and is background at t lies within the keep-list's dilation margin
as long as the scene moves less than the margin per step, and a second row map would cost
more than it gives. A masked step needs the last step's complete layers of the same
S x H x W and, with motion blocks, the last step to have run the motion (its z(t-1) and
motion streams are complete): else every patch runs (step 0 and step 1 always do).

Choices where forge4d-arch.md leaves a detail open (the C runtime does the same):
  - the scale footprint uses |z| / |f| (z the view depth of X, f = (fx + fy) / 2), so a
    point behind its camera (random or untrained weights) still gets a positive scale;
  - q = (1, 0, 0, 0) + q_raw is normalised when |q| >= 1e-12, else it is the identity;
  - the fusion output's quaternion: the sign-aligned sum (sign of the dot product, +1 at
    0) normalised, the identity when its norm is below 1e-12, then + fc2[10:14]; the
    output stays pre-activation in the attribute convention of interp (the consumer
    normalises q, exponentiates scales and takes the sigmoid of the opacity logit).
"""
import dataclasses

import torch
import torch.nn as nn
import torch.nn.functional as F

from vggt_ref import VGGT, DPTHead, Config, LayerScale, Mlp, rope2d, pose_to_extri_intri  # noqa: F401

GAUSS_CH = 14            # dp 3 | dc 3 | o 1 | s 3 | q 4
SH_C0 = 0.28209479177387814
OPACITY_BIAS = 4.0
SCALE_LOG_MIN, SCALE_LOG_MAX = -8.0, 4.0
QUAT_EPS = 1e-12
GAUGE_T_EPS = 1e-6       # |T| below this (model units / metres): no ratio from that view
STATE_TOKENS = 16        # N_s
MOTION_CH = 3
FUSION_ATTRS = 14        # mu 3 | colour 3 | logit(opacity) 1 | log(scale) 3 | q 4
FUSION_HIDDEN = 64


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


class CrossAttention(nn.Module):
    """Queries from one token set, keys / values from another: q, kv, proj Linears."""

    def __init__(self, dim, heads):
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(dim, 2 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, xq, xkv, pos=None, pos_k=None):
        """xq [n, tq, C], xkv [n, tk, C]; pos [n, tq, 2] for q and (pos_k None) k, or None;
        pos_k [n, tk, 2] when the keys sit elsewhere (masked motion: kept queries, full keys)."""
        n, tq, c = xq.shape
        tk, d = xkv.shape[1], c // self.heads
        q = self.q(xq).reshape(n, tq, self.heads, d).transpose(1, 2)
        kv = self.kv(xkv).reshape(n, tk, 2, self.heads, d).permute(2, 0, 3, 1, 4)
        k, v = kv[0], kv[1]
        if pos is not None:
            q = rope2d(q, pos)
            k = rope2d(k, pos if pos_k is None else pos_k)
        a = torch.softmax((q @ k.transpose(-1, -2)) * d ** -0.5, dim=-1)
        return self.proj((a @ v).transpose(1, 2).reshape(n, tq, c))


def zero_ls(dim):
    ls = LayerScale(dim)
    nn.init.zeros_(ls.gamma)
    return ls


class StateBlock(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        c, hd = cfg.embed_dim, cfg.num_heads
        ln = lambda: nn.LayerNorm(c, eps=1e-5)  # noqa: E731
        self.norm_x, self.norm_s = ln(), ln()
        self.attn_r = CrossAttention(c, hd)
        self.ls_r = zero_ls(c)
        self.norm_s2, self.norm_x2 = ln(), ln()
        self.attn_w = CrossAttention(c, hd)
        self.ls_w = zero_ls(c)
        self.norm_m = ln()
        self.mlp = Mlp(c, int(c * cfg.mlp_ratio))
        self.ls_m = zero_ls(c)

    def forward(self, x, s):
        """x [N, C] (all views), s [N_s, C] (the state of t-1) -> x, s'."""
        x = x + self.ls_r(self.attn_r(self.norm_x(x)[None], self.norm_s(s)[None])[0])
        s = s + self.ls_w(self.attn_w(self.norm_s2(s)[None], self.norm_x2(x)[None])[0])
        return x, s + self.ls_m(self.mlp(self.norm_m(s)))


class State(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        self.tokens = nn.Parameter(torch.zeros(STATE_TOKENS, cfg.embed_dim))
        nn.init.normal_(self.tokens, std=0.02)
        self.blocks = nn.ModuleList([StateBlock(cfg) for _ in range(cfg.depth)])


class MotionBlock(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        c = cfg.embed_dim
        self.norm1 = nn.LayerNorm(c, eps=1e-5)
        self.norm_kv = nn.LayerNorm(c, eps=1e-5)
        self.attn = CrossAttention(c, cfg.num_heads)
        self.ls1 = zero_ls(c)
        self.norm2 = nn.LayerNorm(c, eps=1e-5)
        self.mlp = Mlp(c, int(c * cfg.mlp_ratio))
        self.ls2 = zero_ls(c)

    def forward(self, h, zk, pos, pos_k=None):
        """h [S, tq, C], zk [S, tk, C] (per view); pos [tq, 2] (q, and k when pos_k is
        None), pos_k [tk, 2]."""
        p = pos[None].expand(h.shape[0], -1, -1)
        pk = None if pos_k is None else pos_k[None].expand(h.shape[0], -1, -1)
        h = h + self.ls1(self.attn(self.norm1(h), self.norm_kv(zk), p, pk))
        return h + self.ls2(self.mlp(self.norm2(h)))


def motion_layers(cfg):
    """The aggregator layers with a motion block, ascending (checked like the C runtime)."""
    ml = sorted(set(cfg.dpt_layer_idx if cfg.motion_layers is None else cfg.motion_layers))
    if not ml or ml[0] < 0 or ml[-1] >= cfg.depth:
        raise ValueError(f"motion_layers {ml} out of 0..{cfg.depth - 1}")
    missing = set(cfg.dpt_layer_idx) - set(ml)
    if missing:
        raise ValueError(f"motion_layers {ml} lacks the DPT layers {sorted(missing)}")
    return ml


class Motion(nn.Module):
    """Motion blocks at the layers of motion_layers(cfg) only. ModuleDicts keyed by
    the aggregator layer keep the parameter names motion.in_proj.{l} / motion.blocks.{l}
    of the all-layer design, so a checkpoint of that design loads with every layer set."""

    def __init__(self, cfg):
        super().__init__()
        c = cfg.embed_dim
        self.layers = motion_layers(cfg)
        self.in_proj = nn.ModuleDict({str(l): nn.Linear(2 * c, c) for l in self.layers})
        self.blocks = nn.ModuleDict({str(l): MotionBlock(cfg) for l in self.layers})

    def inputs(self, layers):
        """z_l = in_proj_l(F_l) for every motion layer l -> {l: z_l}; layers [S, P', D]."""
        return {l: self.in_proj[str(l)](layers[l]) for l in self.layers}

    def forward(self, zq, zk, pos):
        """{l: motion stream h after block l} (queries from zq, keys from zk)."""
        h, hs = None, {}
        for l in self.layers:
            h = zq[l] if h is None else h + zq[l]
            h = self.blocks[str(l)](h, zk[l], pos)
            hs[l] = h
        return hs


class FusionMLP(nn.Module):
    def __init__(self):
        super().__init__()
        self.fc1 = nn.Linear(2 * FUSION_ATTRS + 2, FUSION_HIDDEN)
        self.fc2 = nn.Linear(FUSION_HIDDEN, FUSION_ATTRS)
        nn.init.zeros_(self.fc2.weight)
        nn.init.zeros_(self.fc2.bias)


def fuse_pairs(fusion, at, am, a, D):
    """forge4d-arch.md 6. at, am [N, 14] (attrs of t and t-1, deformed to t'), a, D [N]
    -> [N, 14] pre-activation: average_pairs + fc2(GELU(fc1(x)))."""
    x = torch.cat([at, am, a[:, None], D[:, None]], dim=-1)
    return average_pairs(at, am) + fusion.fc2(F.gelu(fusion.fc1(x)))


def average_pairs(at, am):
    """What fusion adds its MLP's output to (and all an untrained one gives, interp's
    averaging): the mean of the first 10 attributes, q the normalised sign-aligned sum
    (the identity below QUAT_EPS)."""
    mean = 0.5 * (at[:, :10] + am[:, :10])
    qt, qm = at[:, 10:], am[:, 10:]
    sg = torch.where((qt * qm).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(at.dtype)
    qs = qt + sg * qm
    n = qs.norm(dim=-1, keepdim=True)
    ident = torch.zeros_like(qs)
    ident[:, 0] = 1.0
    q = torch.where(n >= QUAT_EPS, qs / torch.clamp(n, min=QUAT_EPS), ident)
    return torch.cat([mean, q], dim=-1)


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
    """VGGT + Forge4D's stage-1 heads; with stream=True also the state blocks, motion
    blocks, motion head and fusion MLP (stages 2-3). forward() returns VGGT's dict plus
    the new checkpoints (see make_fixtures.py); step() runs one time step."""

    def __init__(self, cfg=None, stream=False):
        super().__init__(cfg)
        self.gaussian_head = DPTHead(self.cfg, GAUSS_CH, "none")
        last = self.gaussian_head.scratch.output_conv2[2]
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        self.scale_head = ScaleHead(self.cfg)
        self.stream = stream
        if stream:
            self.state = State(self.cfg)
            self.motion = Motion(self.cfg)
            mf = self.cfg.motion_dpt_features or self.cfg.dpt_features
            self.motion_head = DPTHead(dataclasses.replace(self.cfg, dpt_features=mf), MOTION_CH,
                                       "none", in_dim=self.cfg.embed_dim)
            last = self.motion_head.scratch.output_conv2[2]
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)
            self.fusion = FusionMLP()

    def new_stream(self):
        """t = 0: every layer's state is state.tokens, no previous step."""
        return {"s": [self.state.tokens.detach().clone() for _ in range(self.cfg.depth)],
                "z": None, "shape": None}

    @torch.no_grad()
    def step(self, images, st):
        """One time step; st (new_stream) is updated in place."""
        S, _, H, W = images.shape
        s_new = list(st["s"])

        def after_global(i, x, pos):
            x, s_new[i] = self.state.blocks[i](x, st["s"][i].to(x.dtype))
            return x

        out = self.forward(images, after_global)
        layers = out.pop("_layers")
        st["s"] = s_new
        for i, s in enumerate(s_new):
            out[f"state{i}"] = s
        ns = 1 + self.cfg.num_register_tokens
        h, w = H // self.cfg.patch_size, W // self.cfg.patch_size
        pos = torch.zeros(ns + h * w, 2, dtype=torch.int64)
        rr, cc = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
        pos[ns:, 0] = rr.flatten() + 1
        pos[ns:, 1] = cc.flatten() + 1
        z = self.motion.inputs(layers)
        out["has_motion"] = st["z"] is not None and st["shape"] == (S, H, W)
        if out["has_motion"]:
            g = out["gauge"][0]
            for tag, zq, zk, key in (("m1h", z, st["z"], "m1"), ("m2h", st["z"], z, "m2")):
                hs = self.motion(zq, zk, pos)
                for L in self.cfg.dpt_layer_idx:
                    out[f"motion.{tag}{L}"] = hs[L]
                hl = [hs.get(L) for L in range(self.cfg.depth)]  # the head reads L_dpt only
                m, _ = self.motion_head(hl, H, W, {}, "motion_head")
                out[f"motion_head.{key}"] = m
            out["motion_bwd"] = out["motion_head.m1"] / g
            out["motion_fwd_prev"] = out["motion_head.m2"] / g
            st["h"] = {(tag, L): out[f"motion.{tag}{L}"] for tag in ("m1h", "m2h")
                       for L in self.cfg.dpt_layer_idx}
        else:
            st["h"] = None
        st["z"], st["shape"], st["layers"] = z, (S, H, W), layers
        return out

    def _outputs(self, images, layers):
        """The heads on full aggregator layers [S, P', D] (VGGT.forward + forward())."""
        S, _, H, W = images.shape
        out = {}
        for L in sorted(set(self.cfg.dpt_layer_idx) | {self.cfg.depth - 1}):
            out[f"layer{L}"] = layers[L]
        poses = self.camera_head(layers[-1])
        out["pose_enc"] = poses[-1]
        out["extrinsic"], out["intrinsic"] = pose_to_extri_intri(poses[-1], H, W)
        out["depth"], out["depth_conf"] = self.depth_head(layers, H, W, out, "depth_head")
        out["world_points"], out["world_points_conf"] = self.point_head(layers, H, W, out, "point_head")
        raw, _ = self.gaussian_head(layers, H, W, out, "gaussian_head")
        out["gaussian_raw"] = raw
        act = gaussian_activate(raw, out["world_points"], images, out["extrinsic"], out["intrinsic"])
        g = self.scale_head(layers[-1])
        out["gauge"] = g.reshape(1)
        pos, scale, ext = metric_recovery(g, act, out["extrinsic"])
        out["gaussians_pos"] = pos
        out["gaussians_scale"] = scale
        return out

    @torch.no_grad()
    def step_masked(self, images, keep, st):
        """One time step where only the kept patches run (keep [S, P] bool; MASKED STEP
        in the module docstring). Falls back to step() (every patch) when the stream has
        no complete last step of this S x H x W that ran the motion. out["masked"] says
        which ran."""
        S, _, H, W = images.shape
        if st.get("layers") is None or st["shape"] != (S, H, W) or st.get("h") is None:
            out = self.step(images, st)
            out["masked"] = False
            return out
        p, ns = self.cfg.patch_size, 1 + self.cfg.num_register_tokens
        h, w = H // p, W // p
        P1 = ns + h * w
        kept = [torch.nonzero(keep[f]).flatten().tolist() for f in range(S)]
        rows = [list(range(ns)) + [ns + k for k in kept[f]] for f in range(S)]
        s_new = list(st["s"])

        def after_global(i, x, pos):
            x, s_new[i] = self.state.blocks[i](x, st["s"][i].to(x.dtype))
            return x

        packed = self.aggregator.forward_kept(images, kept, after_global)
        layers = []
        for L in range(self.cfg.depth):
            comp = st["layers"][L].clone()
            for f in range(S):
                comp[f, rows[f]] = packed[L][f]
            layers.append(comp)
        out = self._outputs(images, layers)
        st["s"] = s_new
        for i, s in enumerate(s_new):
            out[f"state{i}"] = s
        pos = torch.zeros(P1, 2, dtype=torch.int64)
        rr, cc = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
        pos[ns:, 0] = rr.flatten() + 1
        pos[ns:, 1] = cc.flatten() + 1
        zp = st["z"]
        z = {}
        for L in self.motion.layers:
            zl = zp[L].clone()
            for f in range(S):
                zl[f, rows[f]] = self.motion.in_proj[str(L)](packed[L][f])
            z[L] = zl
        g = out["gauge"][0]
        drop = torch.ones(S, H, W, dtype=torch.bool)     # pixels of dropped patches
        for f in range(S):
            for k in kept[f]:
                drop[f, (k // w) * p:(k // w + 1) * p, (k % w) * p:(k % w + 1) * p] = False
        hs_new = {}
        for tag, zq, zk, key in (("m1h", z, zp, "m1"), ("m2h", zp, z, "m2")):
            hf = {L: st["h"][(tag, L)].clone() for L in self.cfg.dpt_layer_idx}
            for f in range(S):
                hq = None
                for L in self.motion.layers:
                    q = zq[L][f:f + 1, rows[f]]
                    hq = q if hq is None else hq + q
                    hq = self.motion.blocks[str(L)](hq, zk[L][f:f + 1], pos[rows[f]], pos)
                    if L in hf:
                        hf[L][f, rows[f]] = hq[0]
            hs = [hf.get(L) for L in range(self.cfg.depth)]
            m, _ = self.motion_head(hs, H, W, {}, "motion_head")
            m = torch.where(drop[..., None], torch.zeros_like(m), m)
            for L in self.cfg.dpt_layer_idx:
                out[f"motion.{tag}{L}"] = hf[L]
                hs_new[(tag, L)] = hf[L]
            out[f"motion_head.{key}"] = m
        out["motion_bwd"] = out["motion_head.m1"] / g
        out["motion_fwd_prev"] = out["motion_head.m2"] / g
        out["has_motion"] = True
        out["masked"] = True
        st["z"], st["h"], st["layers"] = z, hs_new, layers
        return out

    @torch.no_grad()
    def forward(self, images, after_global=None):
        S, _, H, W = images.shape
        out = super().forward(images, after_global)
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
