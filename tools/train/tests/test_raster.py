"""raster.py against the firmware's rasterizer (forward) and finite differences (backward).

Run: /usr/bin/python3 -m unittest discover -s tools/train/tests -v
The forward test needs f4d-scene and f4d-render: $F4D_BUILD (default ./build) or
$F4D_SCENE_BIN / $F4D_RENDER_BIN; it is skipped without them.
"""
import os
import subprocess
import sys
import tempfile
import unittest

import numpy as np
import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
import data  # noqa: E402
import raster  # noqa: E402

ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
BUILD = os.environ.get("F4D_BUILD", os.path.join(ROOT, "build"))
SCENE = os.environ.get("F4D_SCENE_BIN", os.path.join(BUILD, "tools", "f4d-scene", "f4d-scene"))
RENDER = os.environ.get("F4D_RENDER_BIN", os.path.join(BUILD, "tools", "f4d-render", "f4d-render"))


@unittest.skipUnless(os.access(SCENE, os.X_OK) and os.access(RENDER, os.X_OK), "f4d-scene / f4d-render not built")
class ForwardMatchesFirmware(unittest.TestCase):
    def test_venue_views(self):
        torch.set_num_threads(1)
        with tempfile.TemporaryDirectory() as d:
            take = os.path.join(d, "take")
            # 72x56: neither side a multiple of 16 (partial tiles), 3 people-ish seeds vary
            for seed in (11, 12):
                subprocess.run([SCENE, "venue", "--seed", str(seed), "--frames", "1", "--size", "72x56",
                                "--ply", "--person-gaussians", "2000", "-o", take], check=True,
                               stdout=subprocess.DEVNULL)
                pos, sc, rot, op, rgb = raster.read_ply(os.path.join(take, "gaussians_t0.ply"))
                for rig in ("rig.json", "eval_rig.json"):
                    K, w2c = data.load_rig(os.path.join(take, rig))
                    for v in range(K.shape[0]):
                        ref = os.path.join(d, "ref.npy")
                        subprocess.run([RENDER, "--ply", os.path.join(take, "gaussians_t0.ply"), "--rig",
                                        os.path.join(take, rig), "--camera", str(v), "-o",
                                        os.path.join(d, "ref.png"), "--rgb-npy", ref, "--background",
                                        "0.2,0.5,0.7", "--threads", "1"], check=True, stdout=subprocess.DEVNULL)
                        want = torch.from_numpy(np.load(ref))
                        got = raster.render(pos, sc, rot, op, rgb, w2c[v], K[v], 72, 56,
                                            bg=torch.tensor([0.2, 0.5, 0.7]))["rgb"]
                        err = (got - want).abs().max().item()
                        p = raster.psnr(got, want)
                        # float32 both sides: differences are rounding only (seen: < 1e-6)
                        self.assertLess(err, 1e-3, f"seed {seed} {rig} view {v}: max error {err}")
                        self.assertGreater(p, 80.0, f"seed {seed} {rig} view {v}: PSNR {p}")

    def test_alpha_clamp_and_stop_rule(self):
        """Many opaque Gaussians stacked on one pixel: the 0.99 clamp and the stop before
        T < 1e-4 decide the colour; the firmware agrees."""
        torch.set_num_threads(1)
        n = 6
        pos = torch.tensor([[0.0, 0.0, 2.0 + 0.1 * i] for i in range(n)])
        sc = torch.full((n, 3), 0.05)
        rot = torch.tensor([[1.0, 0, 0, 0]] * n)
        op = torch.tensor([1.0, 0.999, 0.5, 1.0, 1.0, 1.0])
        rgb = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1, 1, 0], [0, 1, 1], [1, 0, 1]])
        with tempfile.TemporaryDirectory() as d:
            ply = os.path.join(d, "g.ply")
            write_ply(ply, pos, sc, rot, op, rgb)
            rigp = os.path.join(d, "rig.json")
            with open(rigp, "w") as f:
                f.write('{"cameras": [{"name": "c", "width": 32, "height": 24, "fx": 30, "fy": 30, "cx": 16, '
                        '"cy": 12, "world_to_camera": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}]}')
            subprocess.run([RENDER, "--ply", ply, "--rig", rigp, "--camera", "c", "-o", os.path.join(d, "r.png"),
                            "--rgb-npy", os.path.join(d, "r.npy"), "--threads", "1"], check=True,
                           stdout=subprocess.DEVNULL)
            want = torch.from_numpy(np.load(os.path.join(d, "r.npy")))
            pos2, sc2, rot2, op2, rgb2 = raster.read_ply(ply)
            K, w2c = data.load_rig(rigp)
            got = raster.render(pos2, sc2, rot2, op2, rgb2, w2c[0], K[0], 32, 24)["rgb"]
            self.assertLess((got - want).abs().max().item(), 1e-4)


def write_ply(path, pos, sc, rot, op, rgb):
    """INRIA PLY with the 14 required properties (logit opacity, log scale)."""
    n = pos.shape[0]
    o = torch.logit(op.clamp(1e-6, 1 - 1e-6))
    cols = torch.cat([pos, (rgb - 0.5) / 0.28209479177387814, o[:, None], torch.log(sc), rot], 1).numpy()
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]
    hdr = "ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % n
    hdr += "".join("property float %s\n" % k for k in names) + "end_header\n"
    with open(path, "wb") as f:
        f.write(hdr.encode())
        f.write(cols.astype("<f4").tobytes())


class GradientsMatchFiniteDifferences(unittest.TestCase):
    def test_gradcheck_float64(self):
        torch.manual_seed(3)
        n, W, H = 7, 20, 18
        pos = torch.cat([torch.rand(n, 2) * 0.8 - 0.4, 2.0 + torch.rand(n, 1)], 1).double()
        sc = (0.03 + 0.06 * torch.rand(n, 3)).double()
        rot = torch.randn(n, 4).double()
        op = (0.3 + 0.5 * torch.rand(n)).double()
        rgb = torch.rand(n, 3).double()
        K = torch.tensor([[20.0, 0, 10], [0, 20.0, 9], [0, 0, 1]], dtype=torch.float64)
        ang = 0.1
        w2c = torch.tensor([[np.cos(ang), 0, np.sin(ang), 0.05], [0, 1, 0, -0.02],
                            [-np.sin(ang), 0, np.cos(ang), 0.1], [0, 0, 0, 1]], dtype=torch.float64)
        bg = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
        wts = torch.rand(H, W, 3, dtype=torch.float64)

        def f(pos, sc, rot, op, rgb, w2c):
            o = raster.render(pos, sc, rot, op, rgb, w2c, K, W, H, bg=bg, want_depth=True)
            return (o["rgb"] * wts).sum() + 0.1 * o["depth"].sum() + o["alpha"].sum()

        args = [x.clone().requires_grad_(True) for x in (pos, sc, rot, op, rgb, w2c)]
        self.assertTrue(torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-5, rtol=1e-4))

    def test_gradients_flow_to_every_attribute(self):
        torch.manual_seed(4)
        n = 50
        pos = torch.cat([torch.rand(n, 2) - 0.5, 2.0 + torch.rand(n, 1)], 1).requires_grad_(True)
        sc = (0.02 + 0.05 * torch.rand(n, 3)).requires_grad_(True)
        rot = torch.randn(n, 4).requires_grad_(True)
        op = (0.2 + 0.7 * torch.rand(n)).requires_grad_(True)
        rgb = torch.rand(n, 3).requires_grad_(True)
        K = torch.tensor([[40.0, 0, 24], [0, 40.0, 24], [0, 0, 1]])
        o = raster.render(pos, sc, rot, op, rgb, torch.eye(4), K, 48, 48)
        (o["rgb"] ** 2).sum().backward()
        for t in (pos, sc, rot, op, rgb):
            self.assertTrue(torch.isfinite(t.grad).all())
            self.assertGreater(t.grad.abs().sum().item(), 0)


if __name__ == "__main__":
    unittest.main()
