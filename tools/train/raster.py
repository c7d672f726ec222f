"""raster.py - a differentiable 3D Gaussian rasterizer in PyTorch (CPU) with the forward
pass of firmware/gaussians/splat (splat.h, gaussians.md section 1, reference "R"):

  - cull z <= 0.2 and opacity < 1/255; EWA with the Jacobian's tangent clamped to the
    image +- 0.3 tan(fov); +0.3 px^2 dilation; det <= 0 culled;
  - radius ceil(3 sqrt(lambda_max)) (discriminant floored at 0.1); 16x16 tiles, a Gaussian
    visits the tiles of its rectangle only;
  - depth order stable by index (the firmware's stable radix sort on the depth bits);
  - pixel i is evaluated at integer i with the mean at fx x / z + cx - 0.5;
  - alpha = min(0.99, o exp(power)), skipped when power > 0 or alpha < 1/255, and the
    pixel stops before T would fall below 1e-4 (that Gaussian is not added);
  - colour clamped to >= 0, out = C + T bg.

How: every (8x8 sub-tile, Gaussian) pair that the firmware would evaluate is listed
sub-tile-major in depth order and evaluated on the sub-tile's 64 pixels ([pairs, 64]
tensors); transmittance is a per-segment cumulative sum of log(1 - alpha) in float64.
The stop rule is a prefix mask computed without gradient (it is piecewise constant);
the composite is differentiable in every Gaussian attribute (positions, scales,
rotations, opacities, colours) and in the camera's w2c. Memory grows with the pairs x
64, so keep images small (112 x 112).
"""
import math

import torch

TILE = 16
NEAR = 0.2
DILATION = 0.3
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4


def quat_to_mat(q):
    """q [N,4] (w,x,y,z), normalised here -> R [N,3,3] (gaussians.md 1.2)."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(-1, 3, 3)


def project(pos, scale, rot, w2c, fx, fy, cx, cy, W, H):
    """Per-Gaussian screen mean (firmware pixel convention), conic, depth, radius, and
    the visibility mask (culls of the firmware's preprocessing, without gradient)."""
    R, t = w2c[:3, :3], w2c[:3, 3]
    pc = pos @ R.T + t
    tx, ty, tz = pc.unbind(-1)
    tanx, tany = 0.5 * W / fx, 0.5 * H / fy
    lxp, lxn = (W - cx) / fx + 0.3 * tanx, cx / fx + 0.3 * tanx
    lyp, lyn = (H - cy) / fy + 0.3 * tany, cy / fy + 0.3 * tany
    zs = torch.where(tz > NEAR, tz, torch.ones_like(tz))  # keeps culled ones finite
    ux = torch.clamp(tx / zs, -lxn, lxp) * zs
    uy = torch.clamp(ty / zs, -lyn, lyp) * zs
    M = quat_to_mat(rot) * scale[:, None, :]
    S = M @ M.transpose(1, 2)
    zero = torch.zeros_like(zs)
    J = torch.stack([torch.stack([fx / zs, zero, -(fx * ux) / (zs * zs)], -1),
                     torch.stack([zero, fy / zs, -(fy * uy) / (zs * zs)], -1)], 1)  # [N,2,3]
    Tm = J @ R
    cov = Tm @ S @ Tm.transpose(1, 2)
    a = cov[:, 0, 0] + DILATION
    b = cov[:, 0, 1]
    c = cov[:, 1, 1] + DILATION
    det = a * c - b * b
    ok = (tz > NEAR) & (det > 0)
    dets = torch.where(ok, det, torch.ones_like(det))
    conic = torch.stack([c / dets, -b / dets, a / dets], -1)
    with torch.no_grad():
        mid = 0.5 * (a + c)
        disc = torch.sqrt(torch.clamp(mid * mid - dets, min=0.1))
        radius = torch.ceil(3.0 * torch.sqrt(mid + disc))
        ok = ok & torch.isfinite(radius)
    pw = 1.0 / (zs + 1e-7)
    mx = fx * tx * pw + cx - 0.5
    my = fy * ty * pw + cy - 0.5
    return mx, my, conic, tz, radius, ok


SUB = 8  # the PyTorch side evaluates 8x8 sub-tiles of the firmware's 16x16 tiles


class PairBudget(RuntimeError):
    """More (sub-tile, Gaussian) pairs than the caller allows (huge Gaussians)."""


def pair_lists(mx, my, conic_abc, radius, tz, ok, opacity, W, H, max_pairs=600_000):
    """(sub-tile, Gaussian) pairs: sub-tiles inside the Gaussian's 16x16-tile rectangle
    (the firmware's binning) that meet the box where its alpha can reach 1/255
    (|dx| <= sqrt(k2 a), k2 = 2 ln(255 o)): every other pixel skips it in the firmware too.
    Returns (sub-tile id, Gaussian id) sorted sub-tile-major, depth order inside (ties by
    index)."""
    gx, gy = (W + TILE - 1) // TILE, (H + TILE - 1) // TILE
    sx_n, sy_n = (W + SUB - 1) // SUB, (H + SUB - 1) // SUB
    with torch.no_grad():
        x0 = torch.clamp((mx - radius) / TILE, 0, gx).to(torch.int64)
        y0 = torch.clamp((my - radius) / TILE, 0, gy).to(torch.int64)
        x1 = torch.clamp((mx + radius + TILE - 1) / TILE, 0, gx).to(torch.int64)
        y1 = torch.clamp((my + radius + TILE - 1) / TILE, 0, gy).to(torch.int64)
        a_, c_ = conic_abc
        k2 = torch.clamp(2.0 * torch.log(255.0 * opacity.clamp(min=1e-30)), min=0.0)
        ex = torch.sqrt(k2 * a_) * 1.0001 + 0.01
        ey = torch.sqrt(k2 * c_) * 1.0001 + 0.01
        r = TILE // SUB
        sx0 = torch.maximum(r * x0, torch.ceil((mx - ex - (SUB - 1)) / SUB).clamp(-1, sx_n).to(torch.int64))
        sx1 = torch.minimum(torch.minimum(r * x1, torch.tensor(sx_n)) - 1,
                            torch.floor((mx + ex) / SUB).clamp(-1, sx_n).to(torch.int64))
        sy0 = torch.maximum(r * y0, torch.ceil((my - ey - (SUB - 1)) / SUB).clamp(-1, sy_n).to(torch.int64))
        sy1 = torch.minimum(torch.minimum(r * y1, torch.tensor(sy_n)) - 1,
                            torch.floor((my + ey) / SUB).clamp(-1, sy_n).to(torch.int64))
        nx, ny = (sx1 - sx0 + 1).clamp(min=0), (sy1 - sy0 + 1).clamp(min=0)
        vis = ok & ((x1 - x0) * (y1 - y0) > 0) & (nx * ny > 0)
        gid = torch.nonzero(vis).flatten()
        gid = gid[torch.sort(tz[gid], stable=True).indices]  # depth order, ties by index
        cnt = (nx * ny)[gid]
        if gid.numel() == 0 or int(cnt.sum()) == 0:
            e = torch.zeros(0, dtype=torch.int64)
            return e, e
        if int(cnt.sum()) > max_pairs:
            raise PairBudget(f"{int(cnt.sum())} (sub-tile, Gaussian) pairs, budget {max_pairs}")
        g = torch.repeat_interleave(gid, cnt)
        rank = torch.repeat_interleave(torch.arange(gid.numel()), cnt)
        start = torch.cumsum(cnt, 0) - cnt
        k = torch.arange(g.numel()) - torch.repeat_interleave(start, cnt)
        w = nx[g]
        sub = (sy0[g] + torch.div(k, w, rounding_mode="floor")) * sx_n + sx0[g] + k % w
        srt = torch.sort(sub * (gid.numel() + 1) + rank).indices
    return sub[srt], g[srt]


def render(pos, scale, rot, opacity, rgb, w2c, K, W, H, bg=None, want_depth=False, max_pairs=600_000):
    """pos, scale [N,3] (metres, std dev), rot [N,4] (w,x,y,z), opacity [N] in [0,1], rgb
    [N,3]; w2c [4,4] (or [3,4]), K [3,3]; bg [3] or None (black). Returns rgb [H,W,3],
    alpha [H,W] and, with want_depth, the expected depth [H,W] (0 where nothing drew).
    Raises PairBudget beyond max_pairs (sub-tile, Gaussian) pairs (memory ~ 64 x 40 B each)."""
    dt = pos.dtype
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    mx, my, conic, tz, radius, ok = project(pos, scale, rot, w2c, fx, fy, cx, cy, W, H)
    ok = ok & (opacity >= ALPHA_MIN)
    with torch.no_grad():
        det = 1.0 / (conic[:, 0] * conic[:, 2] - conic[:, 1] ** 2)  # dilated a c - b^2
        a_, c_ = conic[:, 2] * det, conic[:, 0] * det
    sub, g = pair_lists(mx, my, (a_, c_), radius, tz, ok, opacity, W, H, max_pairs)
    sx_n, sy_n = (W + SUB - 1) // SUB, (H + SUB - 1) // SUB
    n_sub, P = sx_n * sy_n, SUB * SUB
    oy = torch.div(sub, sx_n, rounding_mode="floor") * SUB
    ox = (sub % sx_n) * SUB
    ly = torch.div(torch.arange(P), SUB, rounding_mode="floor")
    lx = torch.arange(P) % SUB
    dx = mx[g][:, None] - (ox[:, None] + lx[None, :]).to(dt)  # [pairs, 64]
    dy = my[g][:, None] - (oy[:, None] + ly[None, :]).to(dt)
    A, B, C = conic[g, 0:1], conic[g, 1:2], conic[g, 2:3]
    power = -0.5 * (A * dx * dx + C * dy * dy) - B * dx * dy
    alpha = torch.clamp(opacity[g][:, None] * torch.exp(torch.clamp(power, max=0.0)), max=ALPHA_MAX)
    # segments: the pairs of one sub-tile are contiguous; cumulative sums restart there
    n_pairs = g.numel()
    counts = torch.bincount(sub, minlength=n_sub)
    seg_start = (torch.cumsum(counts, 0) - counts)[sub] if n_pairs else sub

    def seg_cumsum(x):  # inclusive cumulative sum inside each sub-tile's segment (float64)
        cs = torch.cumsum(x.to(torch.float64), 0)
        base = torch.cat([torch.zeros_like(cs[:1]), cs])[seg_start]
        return cs - base

    with torch.no_grad():
        use = (power <= 0) & (alpha >= ALPHA_MIN)
        l0 = torch.log1p(-torch.where(use, alpha, torch.zeros_like(alpha)))
        use &= seg_cumsum(l0) >= math.log(T_MIN)  # stop before T < 1e-4 (a prefix)
    a = torch.where(use, alpha, torch.zeros_like(alpha))
    l = torch.log1p(-a)
    cs = seg_cumsum(l)
    Tex = torch.exp(cs - l.to(torch.float64)).to(dt)
    wgt = a * Tex  # [pairs, 64]
    col = torch.clamp(rgb, min=0.0)[g]  # [pairs, 3]
    out = torch.zeros(n_sub, P, 3, dtype=dt).index_add(0, sub, wgt[:, :, None] * col[:, None, :])
    logT = torch.zeros(n_sub, P, dtype=torch.float64).index_add(0, sub, l.to(torch.float64))
    Tf = torch.exp(logT).to(dt)
    if bg is not None:
        out = out + Tf[:, :, None] * bg.to(dt)[None, None, :]

    def unsub(x):  # [sub-tiles, 64, ...] -> [H, W, ...]
        rest = x.shape[2:]
        x = x.reshape(sy_n, sx_n, SUB, SUB, *rest).permute(0, 2, 1, 3, *range(4, 4 + len(rest)))
        return x.reshape(sy_n * SUB, sx_n * SUB, *rest)[:H, :W]

    res = {"rgb": unsub(out), "alpha": unsub(1.0 - Tf)}
    if want_depth:
        d = torch.zeros(n_sub, P, dtype=dt).index_add(0, sub, wgt * tz[g][:, None])
        acc = 1.0 - Tf
        res["depth"] = unsub(torch.where(acc > 0, d / torch.where(acc > 0, acc, torch.ones_like(acc)),
                                         torch.zeros_like(d)))
    return res


def read_ply(path):
    """INRIA PLY (binary little endian, float properties) -> activated tensors, as
    splat_ply_read does (quaternions normalised)."""
    import numpy as np
    with open(path, "rb") as f:
        names, n = [], 0
        while True:
            line = f.readline().decode().strip()
            if line.startswith("element vertex"):
                n = int(line.split()[-1])
            elif line.startswith("property float"):
                names.append(line.split()[-1])
            elif line == "end_header":
                break
        data = np.frombuffer(f.read(4 * len(names) * n), dtype="<f4").reshape(n, len(names))
    col = {k: torch.from_numpy(data[:, i].copy()) for i, k in enumerate(names)}
    st = lambda ks: torch.stack([col[k] for k in ks], -1)
    pos = st(["x", "y", "z"])
    scale = torch.exp(st(["scale_0", "scale_1", "scale_2"]))
    rot = st(["rot_0", "rot_1", "rot_2", "rot_3"])
    rot = rot / rot.norm(dim=-1, keepdim=True)
    opacity = torch.sigmoid(col["opacity"])
    rgb = 0.5 + 0.28209479177387814 * st(["f_dc_0", "f_dc_1", "f_dc_2"])
    return pos, scale, rot, opacity, rgb


def ssim(x, y, window=11, sigma=1.5):
    """SSIM as splat_ssim / 3DGS: x, y [C,H,W] (or [B,C,H,W]) in [0,1]; mean over all."""
    if x.dim() == 3:
        x, y = x[None], y[None]
    C = x.shape[1]
    g = torch.exp(-((torch.arange(window, dtype=x.dtype) - window // 2) ** 2) / (2 * sigma * sigma))
    g = g / g.sum()
    w = (g[:, None] * g[None, :]).expand(C, 1, window, window).contiguous()
    conv = lambda z: torch.nn.functional.conv2d(z, w, padding=window // 2, groups=C)
    mu1, mu2 = conv(x), conv(y)
    s11, s22, s12 = conv(x * x) - mu1 ** 2, conv(y * y) - mu2 ** 2, conv(x * y) - mu1 * mu2
    C1, C2 = 0.01 ** 2, 0.03 ** 2
    m = ((2 * mu1 * mu2 + C1) * (2 * s12 + C2)) / ((mu1 ** 2 + mu2 ** 2 + C1) * (s11 + s22 + C2))
    return m.mean()


def psnr(a, b):
    mse = torch.mean((a - b) ** 2)
    return float("inf") if float(mse) == 0 else -10.0 * math.log10(float(mse))
