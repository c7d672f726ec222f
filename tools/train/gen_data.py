"""gen_data.py - training / validation / test takes for tools/train, made by the C
generator `f4d-scene venue` (firmware/synth/scene + the splat rasterizer: exact ground
truth, about 0.3 s per take on one core).

    /usr/bin/python3 tools/train/gen_data.py --bin build/tools/f4d-scene/f4d-scene \
        --out tools/train/data [--train 240 --val 16 --test 16 --frames 3]

Seeds are fixed per split and disjoint, so the test split is never seen in training:
train = 100000 + i, val = 200000 + i, test = 300000 + i. Each take is a directory
SPLIT/SEED (layout in tools/f4d-scene/venue.c). Re-running skips takes already there.
"""
import argparse
import os
import subprocess
import sys

SPLIT_BASE = {"train": 100000, "val": 200000, "test": 300000}


def split_seeds(split, n):
    return [SPLIT_BASE[split] + i for i in range(n)]


def generate(binary, out, split, n, frames=3, size="112x112", extra=()):
    os.makedirs(os.path.join(out, split), exist_ok=True)
    done = []
    for seed in split_seeds(split, n):
        d = os.path.join(out, split, str(seed))
        if not os.path.exists(os.path.join(d, "take.json")):
            subprocess.run([binary, "venue", "--seed", str(seed), "--frames", str(frames), "--size", size,
                            "-o", d, *extra], check=True, stdout=subprocess.DEVNULL)
        done.append(d)
    return done


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", default="build/tools/f4d-scene/f4d-scene")
    ap.add_argument("--out", default="tools/train/data")
    ap.add_argument("--train", type=int, default=240)
    ap.add_argument("--val", type=int, default=16)
    ap.add_argument("--test", type=int, default=16)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--size", default="112x112")
    a = ap.parse_args()
    for split in ("train", "val", "test"):
        n = getattr(a, split)
        generate(a.bin, a.out, split, n, a.frames, a.size, ("--ply",) if split == "test" else ())
        print(f"{split}: {n} takes in {os.path.join(a.out, split)}", file=sys.stderr)


if __name__ == "__main__":
    main()
