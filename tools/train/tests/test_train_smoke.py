"""Tiny-step training smoke test: on a fixture take (f4d-scene venue, 56x56) and a tiny
Forge4D, a few optimiser steps of each stage lower that stage's loss on the same sample,
the checkpoint / resume path works and the export writes safetensors the converter's
names expect. Skipped without f4d-scene ($F4D_SCENE_BIN or ./build)."""
import json
import os
import random
import subprocess
import sys
import tempfile
import unittest

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
import data  # noqa: E402
import train  # noqa: E402
from test_raster import SCENE  # noqa: E402

TINY = dict(train.SMALL, img_size=56, embed_dim=32, depth=2, num_heads=2, camera_trunk_depth=1,
            camera_num_heads=2, camera_iters=2, dpt_features=8, dpt_out_channels=[8, 8, 16, 16],
            dpt_layer_idx=[0, 0, 1, 1], num_register_tokens=1)


@unittest.skipUnless(os.access(SCENE, os.X_OK), "f4d-scene not built")
class Smoke(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        torch.set_num_threads(1)
        cls.tmp = tempfile.TemporaryDirectory()
        cls.root = cls.tmp.name
        for split, seed in (("train", 1), ("val", 2)):
            os.makedirs(os.path.join(cls.root, split))
            subprocess.run([SCENE, "venue", "--seed", str(seed), "--frames", "2", "--size", "56x56", "--views", "3",
                            "--person-gaussians", "1500", "-o", os.path.join(cls.root, split, str(seed))],
                           check=True, stdout=subprocess.DEVNULL)
        cls.take = data.Take(os.path.join(cls.root, "train", "1"))

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def descend(self, stage, loss_fn, steps=8, lr=2e-3, factor=0.9, first=0, prep=None):
        model = train.make_model(TINY, stream=True, seed=0)
        if prep:
            prep(model)
        params = train.trainable(model, stage)
        opt = torch.optim.Adam(params, lr=lr)
        losses = []
        for _ in range(steps):
            random.seed(0)
            torch.manual_seed(0)
            loss = loss_fn(model)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(float(loss))
        self.assertTrue(all(map(lambda x: x == x, losses)), losses)
        self.assertLess(losses[-1], factor * losses[first], f"stage {stage}: {losses}")
        return model

    def test_stage1_loss_decreases(self):
        smp = train.Sample(self.take, 0, [0, 1])
        self.descend(1, lambda m: train.stage1_losses(m, smp, render=True)[0])

    def test_stage2_loss_decreases(self):
        # LayerScales start at 0: the state's effect grows slowly, so the bar is lower
        self.descend(2, lambda m: train.run_state_seq(m, self.take, [0, 1])[0], lr=2e-2, factor=0.985)

    def test_stage3_loss_decreases(self):
        # the exact-motion term (the mid-time render of an untrained base is noise). The
        # zero-initialised head starts at the exact answer of the static background
        # (most pixels), which any first step leaves: the bar is the fall after it.
        self.descend(3, lambda m: train.run_motion(m, self.take, 1, [0, 1], mid_weight=0.0)[0], lr=3e-4,
                     first=1)

    def gt_keys(self, views):
        """Keys t-1 = 0 and t = 1 as the runtime would hand them to interp if the model were
        exact: true points (view 0's frame, metres), true cameras, the images' colours."""
        keys = []
        for k in (0, 1):
            smp = train.Sample(self.take, k, views, with_eval=False)
            S, H, W = smp.depth.shape
            keys.append(dict(mu=smp.points, sigma=torch.full((S, H, W, 3), 0.01), rot=torch.tensor(
                [1.0, 0, 0, 0]).expand(S, H, W, 4), rgb=smp.images.permute(0, 2, 3, 1),
                opacity=torch.full((S, H, W), 0.9), ext=smp.rel[:, :3], K=smp.K))
        return keys

    def test_stage4_loss_decreases(self):
        # fusion.fc2 starts at 0 (averaging). An untrained base puts its points outside the
        # frustum (no pairs), so the keys handed to interp are the exact ones; the stage's
        # own path (run_keys, motion, pairing, fusion, render) runs unchanged around them
        views = [0, 1]
        keys = self.gt_keys(views)
        real = train.metric_key
        calls = []

        def exact(o):
            calls.append(1)
            return keys[(len(calls) - 1) % 2]

        def loss(m):
            L, logs = train.run_fusion(m, self.take, 1, views)
            self.assertGreater(logs["fused"], 1000)
            return L

        train.metric_key = exact
        try:
            self.descend(4, loss, lr=1e-3, factor=0.95)
        finally:
            train.metric_key = real

    def test_interp_fused_averaging_matches_untrained_mlp(self):
        # with fc2 = 0 the MLP is averaging: both branches give the same Gaussians
        model = train.make_model(TINY, stream=True, seed=0)
        with torch.no_grad():
            outs = train.run_keys(model, self.take, [0, 1], 1)
            km, kt = train.metric_key(outs[0]), train.metric_key(outs[1])
            m = torch.full_like(kt["mu"], 0.01)
            a = train.interp_fused(model, km, kt, m, -m, 0.5, fuse=True)[0]
            b = train.interp_fused(model, km, kt, m, -m, 0.5, fuse=False)[0]
        for x, y in zip(a, b):
            self.assertLess(float((x - y).abs().max()), 1e-5)

    def test_checkpoint_resume_export(self):
        cfgp = os.path.join(self.root, "tiny.json")
        with open(cfgp, "w") as f:
            json.dump(TINY, f)
        ck = os.path.join(self.root, "ck")
        base = [sys.executable, os.path.join(os.path.dirname(HERE), "train.py"), "--data", self.root, "--ckpt-dir",
                ck, "--config", cfgp, "--val-every", "0", "--save-every", "1"]
        subprocess.run(base + ["--stage", "1", "--steps", "2"], check=True, stdout=subprocess.DEVNULL)
        out = subprocess.run(base + ["--stage", "1", "--steps", "3", "--resume"], check=True, capture_output=True,
                             text=True).stdout
        self.assertIn("resumed stage 1 at step 2", out)
        self.assertEqual(torch.load(os.path.join(ck, "stage1.pt"))["state"]["step"], 3)
        subprocess.run(base + ["--export", os.path.join(self.root, "ship")], check=True, stdout=subprocess.DEVNULL)
        with open(os.path.join(self.root, "ship", "forge4d_small.safetensors"), "rb") as f:
            n = int.from_bytes(f.read(8), "little")
            names = json.loads(f.read(n))
        self.assertIn("gaussian_head.scratch.output_conv2.2.weight", names)
        self.assertIn("scale_head.fc2.weight", names)
        self.assertFalse(any(k.startswith(("state.", "motion")) for k in names))
        # the GGUF reader gives back what f4d-convert wrote (when the converter is built)
        conv = os.environ.get("F4D_CONVERT_BIN", "build/tools/f4d-convert/f4d-convert")
        if os.access(conv, os.X_OK):
            import gguf_read
            g = os.path.join(self.root, "ship", "m.gguf")
            subprocess.run([conv, os.path.join(self.root, "ship", "forge4d_small.safetensors"), g, "--config",
                            os.path.join(self.root, "ship", "config.json"), "--type", "f32"], check=True,
                           stdout=subprocess.DEVNULL)
            _, sd = gguf_read.read(g)
            ref = torch.load(os.path.join(ck, "stage1.pt"))["model"]
            for k, v in sd.items():
                self.assertTrue(torch.equal(v, ref[k]), k)


if __name__ == "__main__":
    unittest.main()
