"""data.py - reads a take written by `f4d-scene venue` into torch tensors.

Conventions (splat.h): metres, world z up; cameras OpenCV (x right, y down, z forward),
w2c row-major [R | t]; pixel (i, j) samples image coordinate (i + 0.5, j + 0.5).
"""
import json
import os

import numpy as np
import torch


def load_rig(path):
    with open(path) as f:
        cams = json.load(f)["cameras"]
    K, w2c = [], []
    for c in cams:
        K.append([[c["fx"], 0, c["cx"]], [0, c["fy"], c["cy"]], [0, 0, 1]])
        m = np.array(c["world_to_camera"], dtype=np.float64).reshape(4, 4)
        w2c.append(m)
    return torch.tensor(K, dtype=torch.float32), torch.tensor(np.stack(w2c), dtype=torch.float32)


def unproject(depth, K, w2c):
    """depth [V,H,W] (camera z, m), K [V,3,3], w2c [V,4,4] -> world points [V,H,W,3]."""
    V, H, W = depth.shape
    u = torch.arange(W, dtype=depth.dtype) + 0.5
    v = torch.arange(H, dtype=depth.dtype) + 0.5
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    x = (uu[None] - K[:, 0, 2, None, None]) / K[:, 0, 0, None, None] * depth
    y = (vv[None] - K[:, 1, 2, None, None]) / K[:, 1, 1, None, None] * depth
    pc = torch.stack([x, y, depth], -1)  # camera coordinates
    R, t = w2c[:, :3, :3], w2c[:, :3, 3]
    return torch.einsum("vji,vhwj->vhwi", R, pc - t[:, None, None, :])


class Take:
    """One take: keys 0..T-1, V input views, E evaluation views."""

    def __init__(self, d):
        self.dir = d
        with open(os.path.join(d, "take.json")) as f:
            self.meta = json.load(f)
        ld = lambda n: torch.from_numpy(np.load(os.path.join(d, n + ".npy")))
        self.rgb, self.depth, self.alpha = ld("rgb"), ld("depth"), ld("alpha")
        self.motion_bwd, self.motion_fwd = ld("motion_bwd"), ld("motion_fwd")
        self.K, self.w2c = load_rig(os.path.join(d, "rig.json"))
        self.E = self.meta["eval_views"]
        if self.E:
            self.eval_rgb, self.eval_depth = ld("eval_rgb"), ld("eval_depth")
            self.eval_K, self.eval_w2c = load_rig(os.path.join(d, "eval_rig.json"))
        self.mid_rgb = ld("mid_rgb") if self.meta["frames"] > 1 else None
        self.sky = torch.tensor(self.meta["sky"], dtype=torch.float32)
        self.T, self.V = self.rgb.shape[0], self.rgb.shape[1]
        self.H, self.W = self.rgb.shape[2], self.rgb.shape[3]

    def points(self, k):
        """World points of key k [V,H,W,3] (m) and their validity mask (alpha > 0.5)."""
        return unproject(self.depth[k], self.K, self.w2c), self.alpha[k] > 0.5


def list_takes(root, split):
    d = os.path.join(root, split)
    if not os.path.isdir(d):
        return []
    return sorted(os.path.join(d, x) for x in os.listdir(d) if os.path.exists(os.path.join(d, x, "take.json")))
