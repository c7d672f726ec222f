#!/usr/bin/python3
"""make_fixtures.py - tiny random-weight VGGT parity fixtures for tests/model/.

    /usr/bin/python3 tools/reference/make_fixtures.py [OUT_DIR] [--forge4d-only | --masked-only]

For each tiny config it writes OUT_DIR/<config>/:
    config.json            the f4d-convert config (the issue's keys)
    weights.safetensors    the random state_dict, F32, released parameter names
    s<S>/input.npy         [S, 3, H, W] in [0, 1]
    s<S>/<checkpoint>.npy  intermediates and outputs, channels as PyTorch gives them

The model runs in float64 on float32-representable weights and inputs, so the
fixtures are the exact answer and a C port in float32 is judged by its own
rounding only. Results are saved as float32.
"""
import dataclasses
import json
import os
import struct
import sys

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from vggt_ref import VGGT, Config, aa_bicubic_weights  # noqa: E402
from forge4d_ref import Forge4D  # noqa: E402

CONFIGS = {
    # DINO patch embed; 42x70 input: pos-embed grid 4x4 -> 3x5 (down rows, up columns).
    "tiny": dict(cfg=Config(img_size=56, patch_size=14, embed_dim=32, depth=5, num_heads=2,
                            mlp_ratio=2.0, num_register_tokens=2, patch_embed="dino",
                            dino_depth=2, dino_num_heads=2, camera_trunk_depth=2,
                            camera_num_heads=2, camera_iters=4, dpt_features=16,
                            dpt_out_channels=[8, 16, 24, 24], dpt_layer_idx=[0, 2, 3, 4]),
                 H=42, W=70, views=[1, 3, 4]),
    # conv patch embed, odd grid (3x3 -> level 3 rounds up to 2x2).
    "tiny_conv": dict(cfg=Config(img_size=42, patch_size=14, embed_dim=16, depth=3, num_heads=1,
                                 mlp_ratio=4.0, num_register_tokens=1, patch_embed="conv",
                                 dino_depth=0, dino_num_heads=1, camera_trunk_depth=1,
                                 camera_num_heads=1, camera_iters=2, dpt_features=8,
                                 dpt_out_channels=[4, 8, 8, 12], dpt_layer_idx=[0, 1, 1, 2]),
                      H=42, W=42, views=[2]),
}


def init_weights(model, gen):
    """Random weights that keep every path active: LayerScales near 1 (not the
    0.01 init, which would hide most of the network), moderate logits."""
    sd = model.state_dict()
    for name, t in sd.items():
        if name.endswith("ls1.gamma") or name.endswith("ls2.gamma"):
            v = 0.5 + 0.5 * torch.rand(t.shape, generator=gen)
        elif "norm" in name and name.endswith("weight"):
            v = 1.0 + 0.2 * torch.randn(t.shape, generator=gen)
        elif name.endswith("bias"):
            v = 0.1 * torch.randn(t.shape, generator=gen)
        elif name.endswith("weight"):
            fan_in = t[0].numel() if "resize_layers.0" not in name and "resize_layers.1" not in name \
                else t.shape[0]
            v = torch.randn(t.shape, generator=gen) / (fan_in ** 0.5)
        else:  # tokens, pos_embed
            v = 0.5 * torch.randn(t.shape, generator=gen)
        sd[name] = v.to(torch.float32)
    # FoV: positive (about 1 rad) so the intrinsics stay finite.
    sd["camera_head.pose_branch.fc2.weight"] *= 0.2
    sd["camera_head.pose_branch.fc2.bias"][7:9] = 0.3
    for h in ("depth_head", "point_head", "gaussian_head"):
        if f"{h}.scratch.output_conv2.2.weight" in sd:
            sd[f"{h}.scratch.output_conv2.2.weight"] *= 0.3
    if "scale_head.fc2.weight" in sd:  # a gauge near 2, well away from the untrained 1
        sd["scale_head.fc2.weight"] *= 0.5
        sd["scale_head.fc2.bias"][0] = 0.7
    model.load_state_dict(sd)


def write_safetensors(path, sd, dtype="F32"):
    header, blobs, off = {}, [], 0
    for name in sorted(sd):
        t = sd[name].detach().contiguous()
        if dtype == "BF16":
            b = t.to(torch.bfloat16).view(torch.int16).numpy().astype("<i2").tobytes()
        elif dtype == "F16":
            b = t.to(torch.float16).numpy().astype("<f2").tobytes()
        else:
            b = t.to(torch.float32).numpy().astype("<f4").tobytes()
        header[name] = {"dtype": dtype, "shape": list(t.shape), "data_offsets": [off, off + len(b)]}
        blobs.append(b)
        off += len(b)
    header["__metadata__"] = {"format": "pt"}
    hj = json.dumps(header, separators=(",", ":")).encode()
    hj += b" " * ((8 - len(hj) % 8) % 8)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(hj)))
        f.write(hj)
        for b in blobs:
            f.write(b)


def check_aa_bicubic():
    """The spec's PIL-style bicubic against torch's antialiased interpolate."""
    for n_in, n_out in ((37, 28), (37, 20), (5, 7), (4, 3), (4, 5)):
        m = torch.tensor(aa_bicubic_weights(n_in, n_out), dtype=torch.float32)
        x = torch.randn(1, 1, n_in, 1)
        ref = F.interpolate(x, size=(n_out, 1), mode="bicubic", antialias=True, align_corners=False)
        err = (m @ x[0, 0, :, 0] - ref[0, 0, :, 0]).abs().max().item()
        assert err < 1e-5, f"aa bicubic {n_in}->{n_out}: {err}"


def vggt_load(img, mode, target):
    """vggt.md 1a (load_and_preprocess_images) on a PIL image, any target size."""
    if img.mode == "RGBA":
        bg = Image.new("RGBA", img.size, (255, 255, 255, 255))
        img = Image.alpha_composite(bg, img)
    img = img.convert("RGB")
    w, h = img.size
    if mode == "pad":
        if w >= h:
            nw, nh = target, round(h * (target / w) / 14) * 14
        else:
            nh, nw = target, round(w * (target / h) / 14) * 14
    else:
        nw, nh = target, round(h * (target / w) / 14) * 14
    a = np.asarray(img.resize((nw, nh), Image.Resampling.BICUBIC), dtype=np.float32) / 255.0
    t = torch.from_numpy(a).permute(2, 0, 1)
    if mode == "crop" and nh > target:
        s = (nh - target) // 2
        t = t[:, s:s + target]
    if mode == "pad":
        hp, wp = target - t.shape[1], target - t.shape[2]
        if hp > 0 or wp > 0:
            t = F.pad(t, (wp // 2, wp - wp // 2, hp // 2, hp - hp // 2), value=1.0)
    return t


def vggt_batch(ts):
    H = max(t.shape[1] for t in ts)
    W = max(t.shape[2] for t in ts)
    out = []
    for t in ts:
        hp, wp = H - t.shape[1], W - t.shape[2]
        out.append(F.pad(t, (wp // 2, wp - wp // 2, hp // 2, hp - hp // 2), value=1.0))
    return torch.stack(out)


def prep_fixtures(out_root):
    """Preprocessing fixtures: PIL bicubic as VGGT's loader uses it, small target
    sizes so the files stay small (the rules do not depend on 518)."""
    d = os.path.join(out_root, "prep")
    os.makedirs(d, exist_ok=True)
    rng = np.random.default_rng(7)
    cases = {"rgb_40x30": (30, 40, 3), "rgb_100x77": (77, 100, 3), "rgb_30x50": (50, 30, 3),
             "mono_45x33": (33, 45, 1)}
    imgs = {}
    for name, (h, w, c) in cases.items():
        a = rng.integers(0, 256, size=(h, w, c), dtype=np.uint8)
        # smooth part so bicubic overshoot and clipping both happen
        a[: h // 2] = (np.linspace(0, 255, w)[None, :, None]).astype(np.uint8)
        np.save(os.path.join(d, f"{name}.npy"), a.astype(np.float32))
        imgs[name] = Image.fromarray(a[..., 0] if c == 1 else a, "L" if c == 1 else "RGB")
    for name, img in imgs.items():
        for mode in ("crop", "pad"):
            for target in (28, 56):
                t = vggt_load(img, mode, target)
                np.save(os.path.join(d, f"{name}_{mode}{target}.npy"), t.numpy())
    imgs["rgb_40x30"].save(os.path.join(d, "rgb_40x30.png"))
    imgs["rgb_30x50"].save(os.path.join(d, "rgb_30x50.png"))
    b = vggt_batch([vggt_load(imgs["rgb_40x30"], "crop", 56), vggt_load(imgs["rgb_30x50"], "crop", 56)])
    np.save(os.path.join(d, "batch_crop56.npy"), b.numpy())


# Forge4D stage-1 fixture: the tiny VGGT + gaussian_head + scale_head, 2 views. Only
# the new checkpoints are written (the VGGT ones are covered by `tiny`).
F4D_SAVE = ("input", "gaussian_head.level0", "gaussian_head.level1", "gaussian_head.level2",
            "gaussian_head.level3", "gaussian_head.fused", "gaussian_raw", "gaussian_head.mu",
            "gaussian_head.sigma", "gauge", "gaussians_pos", "gaussians_scale", "gaussians_rot",
            "gaussians_opacity", "gaussians_rgb", "extrinsic_metric")

# Hard cases: the same weights with one edit each, made in float32 exactly as the C test
# (tests/model/test_forge4d.c) makes them on the converted f32 file.
F4D_HARD = {
    # near-zero camera translations: the translation rows of the pose branch x 1e-6
    "near_zero_t": ("gauge", "extrinsic", "extrinsic_metric"),
    # huge predicted scales: s logits +60, -60 and 1e30 (the exp clamp)
    "huge_scale": ("gaussians_scale",),
    # a zero quaternion: q_raw = (-1, 0, 0, 0) at every pixel
    "zero_quat": ("gaussians_rot",),
}


def f4d_hard_edit(sd, case):
    sd = {k: v.clone() for k, v in sd.items()}
    if case == "near_zero_t":
        k = torch.tensor(1e-6, dtype=torch.float32)
        sd["camera_head.pose_branch.fc2.weight"][0:3] *= k
        sd["camera_head.pose_branch.fc2.bias"][0:3] *= k
    elif case == "huge_scale":
        b = sd["gaussian_head.scratch.output_conv2.2.bias"]
        b[7] += 60.0
        b[8] -= 60.0
        b[9] = 1e30
    elif case == "zero_quat":
        sd["gaussian_head.scratch.output_conv2.2.weight"][10:14] = 0.0
        sd["gaussian_head.scratch.output_conv2.2.bias"][10:14] = torch.tensor([-1.0, 0.0, 0.0, 0.0])
    return sd


def forge4d_fixtures(out_root):
    cfg, H, W, S = CONFIGS["tiny"]["cfg"], 42, 70, 2
    gen = torch.Generator().manual_seed(4242)
    model = Forge4D(cfg).eval()
    init_weights(model, gen)
    d = os.path.join(out_root, "tiny_f4d")
    os.makedirs(d, exist_ok=True)
    sd = {k: v.clone() for k, v in model.state_dict().items()}
    write_safetensors(os.path.join(d, "weights.safetensors"), sd)
    with open(os.path.join(d, "config.json"), "w") as f:
        json.dump({k: getattr(cfg, k) for k in cfg.__dataclass_fields__}, f, indent=1)
        f.write("\n")
    img = torch.rand(S, 3, H, W, generator=gen).to(torch.float32)
    sdir = os.path.join(d, f"s{S}")
    os.makedirs(sdir, exist_ok=True)
    out = model.double()(img.double())
    out["input"] = img
    for k in F4D_SAVE:
        np.save(os.path.join(sdir, f"{k}.npy"), out[k].to(torch.float32).contiguous().numpy())
    g, sc = out["gauge"].item(), out["gaussians_scale"]
    print(f"tiny_f4d S={S}: gauge {g:.4g}, scale {sc.min().item():.3g}..{sc.max().item():.3g}, "
          f"opacity {out['gaussians_opacity'].min().item():.3g}..{out['gaussians_opacity'].max().item():.3g}")
    for case, keys in F4D_HARD.items():
        m2 = Forge4D(cfg).eval()
        m2.load_state_dict(f4d_hard_edit(sd, case))
        o2 = m2.double()(img.double())
        hdir = os.path.join(d, f"hard_{case}")
        os.makedirs(hdir, exist_ok=True)
        for k in keys:
            v = o2[k].to(torch.float32).contiguous().numpy()
            assert np.isfinite(v).all(), (case, k)
            np.save(os.path.join(hdir, f"{k}.npy"), v)
        print(f"tiny_f4d hard {case}: " + ", ".join(
            f"{k} |max| {o2[k].abs().max().item():.3g}" for k in keys))


def read_safetensors(path):
    with open(path, "rb") as f:
        n = struct.unpack("<Q", f.read(8))[0]
        header = json.loads(f.read(n))
        blob = f.read()
    sd = {}
    for name, e in header.items():
        if name == "__metadata__":
            continue
        assert e["dtype"] == "F32", name
        a, b = e["data_offsets"]
        sd[name] = torch.from_numpy(np.frombuffer(blob[a:b], dtype="<f4").copy().reshape(e["shape"]))
    return sd


# Foreground-only Eval (model_eval_masked) on the committed `tiny` weights, 3 views:
# the previous Eval is the full run on s3/input.npy; this one runs a new input with
# view 0 partly kept, view 1 empty (special tokens only) and view 2 all kept.
MASKED_KEEP = [[0, 1, 0, 1, 1, 0, 0, 1, 0, 0, 1, 0, 0, 0, 1],
               [0] * 15,
               [1] * 15]


def masked_fixtures(out_root):
    spec = CONFIGS["tiny"]
    cfg, H, W = spec["cfg"], spec["H"], spec["W"]
    d = os.path.join(out_root, "tiny")
    model = VGGT(cfg).eval()
    model.load_state_dict(read_safetensors(os.path.join(d, "weights.safetensors")))
    model = model.double()
    prev = torch.from_numpy(np.load(os.path.join(d, "s3", "input.npy")))
    gen = torch.Generator().manual_seed(777)
    img = torch.rand(3, 3, H, W, generator=gen).to(torch.float32)
    keep = torch.tensor(MASKED_KEEP, dtype=torch.bool)
    with torch.no_grad():
        prev_layers = model.aggregator(prev.double(), {})
    out = model.forward_masked(img.double(), keep, prev_layers)
    sdir = os.path.join(d, "masked_s3")
    os.makedirs(sdir, exist_ok=True)
    np.save(os.path.join(sdir, "input.npy"), img.numpy())
    np.save(os.path.join(sdir, "keep.npy"), keep.to(torch.float32).numpy())
    for k, v in out.items():
        if k.startswith("layer") or k in ("pose_enc", "depth", "depth_conf", "world_points",
                                         "world_points_conf"):
            np.save(os.path.join(sdir, f"{k}.npy"), v.to(torch.float32).contiguous().numpy())
    full = model(img.double())
    diff = (full["depth"] - out["depth"]).abs().max().item() / full["depth"].abs().max().item()
    print(f"tiny masked S=3: kept {int(keep.sum())} of {keep.numel()} patches, depth "
          f"{diff:.3g} (relative) from the all-patches run")


# Forge4D stages 2-3 (forge4d-arch.md 4-6): the tiny VGGT + every Forge4D module, a
# sequence of SEQ_T time steps of 2 views at 28x42 (small files). Per step t/<name>.npy:
# the aggregator layers the heads read (state blocks included), the state of every layer
# after the step, gauge, Gaussian positions and scales (metric), and from step 1 on the
# motion stream at the DPT layers of both runs, M1[t] / M2[t-1] in model units and metric.
SEQ_T, SEQ_S, SEQ_H, SEQ_W, SEQ_PAIRS = 4, 2, 28, 42, 64


def seq_init(model, gen):
    """init_weights, then the LayerScales of the new modules and their zero-initialised
    last layers set to nonzero random values: untrained they are the identity / zero /
    averaging, and parity would prove nothing."""
    init_weights(model, gen)
    sd = model.state_dict()
    for name in sd:
        if name.startswith(("state.", "motion.")) and name.endswith(".gamma"):
            sd[name] = (0.3 + 0.4 * torch.rand(sd[name].shape, generator=gen)).to(torch.float32)
    sd["motion_head.scratch.output_conv2.2.weight"] = \
        (torch.randn(sd["motion_head.scratch.output_conv2.2.weight"].shape, generator=gen) * 0.1).float()
    sd["fusion.fc2.weight"] = (torch.randn(sd["fusion.fc2.weight"].shape, generator=gen) * 0.05).float()
    sd["fusion.fc2.bias"] = (torch.randn(sd["fusion.fc2.bias"].shape, generator=gen) * 0.05).float()
    model.load_state_dict(sd)


def fusion_pairs(gen, n):
    """Attribute pairs in interp's convention: positions near each other, colours in
    [0, 1], opacity logits, log-scales of centimetres, unit quaternions (half of the
    t-1 ones sign-flipped), a in (0, 1), D in [0, 0.05]."""
    def attrs(mu):
        q = torch.randn(n, 4, generator=gen, dtype=torch.float64)
        q = q / q.norm(dim=-1, keepdim=True)
        return torch.cat([mu, torch.rand(n, 3, generator=gen, dtype=torch.float64),
                          2 * torch.randn(n, 1, generator=gen, dtype=torch.float64),
                          -4 + torch.randn(n, 3, generator=gen, dtype=torch.float64), q], dim=-1)
    mu = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    at = attrs(mu)
    am = attrs(mu + 0.02 * torch.randn(n, 3, generator=gen, dtype=torch.float64))
    am[::2, 10:] = -am[::2, 10:]
    am[1] = at[1]                 # identical pair
    am[3, 10:] = -at[3, 10:]      # opposite quaternion: the sign alignment cancels nothing
    a = torch.rand(n, generator=gen, dtype=torch.float64)
    D = 0.05 * torch.rand(n, generator=gen, dtype=torch.float64)
    # float32-representable inputs: the C side reads them as float32
    return [v.float().double() for v in (at, am, a, D)]


def forge4d_seq_fixtures(out_root):
    from forge4d_ref import average_pairs, fuse_pairs
    # A motion-layer subset: no block at layer 0 (the stream starts at layer 1), one at
    # layer 2 that the motion head does not read, a repeated DPT layer, and the motion
    # head at half the DPT width.
    cfg = dataclasses.replace(CONFIGS["tiny"]["cfg"], dpt_layer_idx=[1, 3, 3, 4],
                              motion_layers=[1, 2, 3, 4], motion_dpt_features=8)
    # seed: random weights whose motions leave pairs to fuse (sequence/api needs >= 100;
    # 5151 gave 1 with this config: the random cameras and motions put them out of view)
    gen = torch.Generator().manual_seed(5153)
    model = Forge4D(cfg, stream=True).eval()
    seq_init(model, gen)
    d = os.path.join(out_root, "tiny_f4d_seq")
    os.makedirs(d, exist_ok=True)
    sd = {k: v.clone() for k, v in model.state_dict().items()}
    write_safetensors(os.path.join(d, "weights.safetensors"), sd)
    with open(os.path.join(d, "config.json"), "w") as f:
        json.dump({k: getattr(cfg, k) for k in cfg.__dataclass_fields__}, f, indent=1)
        f.write("\n")
    # a slowly moving scene: a base image plus a small change per step
    base = torch.rand(SEQ_S, 3, SEQ_H, SEQ_W, generator=gen)
    frames = []
    for t in range(SEQ_T):
        dt = 0.1 * torch.rand(SEQ_S, 3, SEQ_H, SEQ_W, generator=gen)
        frames.append(torch.clamp(base + dt * t, 0, 1).to(torch.float32))
    m64 = model.double()
    st = m64.new_stream()
    keep = sorted(set(cfg.dpt_layer_idx) | {cfg.depth - 1})
    for t in range(SEQ_T):
        out = m64.step(frames[t].double(), st)
        tdir = os.path.join(d, f"t{t}")
        os.makedirs(tdir, exist_ok=True)
        names = ["gauge", "gaussians_pos", "gaussians_scale"] + [f"layer{L}" for L in keep] + \
                [f"state{i}" for i in range(cfg.depth)]
        if out["has_motion"]:
            names += [f"motion.{tag}{L}" for tag in ("m1h", "m2h") for L in cfg.dpt_layer_idx]
            names += ["motion_head.m1", "motion_head.m2", "motion_bwd", "motion_fwd_prev"]
        assert out["has_motion"] == (t > 0)
        np.save(os.path.join(tdir, "input.npy"), frames[t].numpy())
        for k in names:
            v = out[k].to(torch.float32).contiguous().numpy()
            assert np.isfinite(v).all(), (t, k)
            np.save(os.path.join(tdir, f"{k}.npy"), v)
        msg = f"tiny_f4d_seq t={t}: gauge {out['gauge'].item():.4g}"
        if out["has_motion"]:
            msg += f", |M1| max {out['motion_head.m1'].abs().max().item():.3g}" \
                   f", |M2| max {out['motion_head.m2'].abs().max().item():.3g}"
        print(msg)
    at, am, a, D = fusion_pairs(gen, SEQ_PAIRS)
    with torch.no_grad():
        fo = fuse_pairs(m64.fusion, at, am, a, D)
    fin = torch.cat([at, am, a[:, None], D[:, None]], dim=-1)
    np.save(os.path.join(d, "fusion_in.npy"), fin.to(torch.float32).numpy())
    np.save(os.path.join(d, "fusion_out.npy"), fo.to(torch.float32).numpy())
    print(f"tiny_f4d_seq fusion: {SEQ_PAIRS} pairs, |out - mean| max "
          f"{(fo - average_pairs(at, am)).abs().max().item():.3g}")


# Masked Forge4D steps (Forge4D.step_masked, model_eval_masked with state and motion
# blocks) on the tiny_f4d_seq weights: SEQ_MASK_T steps of 2 views at 28x42 (2 x 3
# patches per view), a keep-list per step. Steps 0 and 1 run every patch whatever the
# keep-list says (no last step that ran the motion); then a partial + an empty view, an
# empty + a partial view, two partial views. Per step masked/t<t>/: input, keep [S, P],
# the tiny_f4d_seq checkpoints.
SEQ_MASK_KEEP = [[[1] * 6, [1] * 6],
                 [[0, 1, 1, 0, 1, 1], [1, 0, 0, 1, 0, 0]],
                 [[0, 1, 1, 0, 0, 1], [0] * 6],
                 [[0] * 6, [1, 1, 0, 0, 0, 1]],
                 [[1, 0, 0, 1, 1, 0], [0, 1, 0, 0, 1, 1]]]


def forge4d_seq_masked_fixtures(out_root):
    d = os.path.join(out_root, "tiny_f4d_seq")
    with open(os.path.join(d, "config.json")) as f:   # the motion-layer subset of tiny_f4d_seq
        cfg = dataclasses.replace(CONFIGS["tiny"]["cfg"], **json.load(f))
    model = Forge4D(cfg, stream=True).eval()
    model.load_state_dict(read_safetensors(os.path.join(d, "weights.safetensors")))
    m64 = model.double()
    gen = torch.Generator().manual_seed(6262)
    base = torch.rand(SEQ_S, 3, SEQ_H, SEQ_W, generator=gen)
    st = m64.new_stream()
    keepL = sorted(set(cfg.dpt_layer_idx) | {cfg.depth - 1})
    for t, kl in enumerate(SEQ_MASK_KEEP):
        dt = 0.1 * torch.rand(SEQ_S, 3, SEQ_H, SEQ_W, generator=gen)
        img = torch.clamp(base + dt * t, 0, 1).to(torch.float32)
        keep = torch.tensor(kl, dtype=torch.bool)
        out = m64.step_masked(img.double(), keep, st)
        assert out["masked"] == (t >= 2) and out["has_motion"] == (t > 0), t
        tdir = os.path.join(d, "masked", f"t{t}")
        os.makedirs(tdir, exist_ok=True)
        np.save(os.path.join(tdir, "input.npy"), img.numpy())
        np.save(os.path.join(tdir, "keep.npy"), keep.to(torch.float32).numpy())
        names = ["gauge", "gaussians_pos", "gaussians_scale"] + [f"layer{L}" for L in keepL] + \
                [f"state{i}" for i in range(cfg.depth)]
        if out["has_motion"]:
            names += [f"motion.{tag}{L}" for tag in ("m1h", "m2h") for L in cfg.dpt_layer_idx]
            names += ["motion_head.m1", "motion_head.m2", "motion_bwd", "motion_fwd_prev"]
        for k in names:
            v = out[k].to(torch.float32).contiguous().numpy()
            assert np.isfinite(v).all(), (t, k)
            np.save(os.path.join(tdir, f"{k}.npy"), v)
        msg = f"tiny_f4d_seq masked t={t}: kept {int(keep.sum())} of {keep.numel()}, " \
              f"masked {out['masked']}"
        if out["has_motion"]:
            msg += f", |M1| max {out['motion_head.m1'].abs().max().item():.3g}" \
                   f", |M2| max {out['motion_head.m2'].abs().max().item():.3g}"
        print(msg)


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    out_root = args[0] if args else os.path.join(
        os.path.dirname(os.path.abspath(__file__)), "..", "..", "tests", "model", "fixtures")
    if "--masked-only" in sys.argv:  # only tiny/masked_s3/ (on the committed tiny weights)
        masked_fixtures(out_root)
        return
    if "--forge4d-only" in sys.argv:  # only tiny_f4d/ (the VGGT fixtures stay as committed)
        forge4d_fixtures(out_root)
        return
    if "--forge4d-seq-only" in sys.argv:  # only tiny_f4d_seq/
        forge4d_seq_fixtures(out_root)
        forge4d_seq_masked_fixtures(out_root)
        return
    if "--forge4d-seq-masked-only" in sys.argv:  # only tiny_f4d_seq/masked/
        forge4d_seq_masked_fixtures(out_root)
        return
    check_aa_bicubic()
    prep_fixtures(out_root)
    for ci, (cname, spec) in enumerate(CONFIGS.items()):
        cfg, H, W = spec["cfg"], spec["H"], spec["W"]
        gen = torch.Generator().manual_seed(1234 + ci)
        model = VGGT(cfg).eval()
        init_weights(model, gen)
        d = os.path.join(out_root, cname)
        os.makedirs(d, exist_ok=True)
        sd = {k: v for k, v in model.state_dict().items()}
        write_safetensors(os.path.join(d, "weights.safetensors"), sd)
        if cname == "tiny_conv":  # the converter's F16 / BF16 input paths
            write_safetensors(os.path.join(d, "weights_f16.safetensors"), sd, "F16")
            write_safetensors(os.path.join(d, "weights_bf16.safetensors"), sd, "BF16")
        with open(os.path.join(d, "config.json"), "w") as f:
            json.dump({k: getattr(cfg, k) for k in cfg.__dataclass_fields__}, f, indent=1)
            f.write("\n")
        model64 = model.double()
        for S in spec["views"]:
            sdir = os.path.join(d, f"s{S}")
            os.makedirs(sdir, exist_ok=True)
            img = torch.rand(S, 3, H, W, generator=gen).to(torch.float32)
            out = model64(img.double())
            np.save(os.path.join(sdir, "input.npy"), img.numpy())
            for k, v in out.items():
                if k.endswith(".logits"):  # the final outputs hold the same numbers
                    continue
                np.save(os.path.join(sdir, f"{k}.npy"), v.to(torch.float32).contiguous().numpy())
            print(f"{cname} S={S} {H}x{W}: {len(out)} tensors, depth range "
                  f"{out['depth'].min().item():.3g}..{out['depth'].max().item():.3g}")
        model.float()
    masked_fixtures(out_root)
    forge4d_fixtures(out_root)
    forge4d_seq_fixtures(out_root)
    forge4d_seq_masked_fixtures(out_root)


if __name__ == "__main__":
    main()
