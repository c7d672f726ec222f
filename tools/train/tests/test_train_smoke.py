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

    def descend(self, stage, loss_fn, steps=8, lr=2e-3, factor=0.9, first=0):
        model = train.make_model(TINY, stream=True, seed=0)
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


if __name__ == "__main__":
    unittest.main()
