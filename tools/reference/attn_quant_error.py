"""attn_quant_error.py - how far quantized attention products land from exact
attention, before writing a kernel for them: the study behind the choice of
bf16 (and not int8) products for int8 models (README, Kernels).

For random q, k, v (d = 64, q and k of standard deviation 1 as after the
aggregator's qk LayerNorm, or 3 for sharper attention) over 1374 and 5496 keys,
the output of softmax(q k^T / sqrt d) v in float64 against:
  bf16   q, k, p and v rounded to bf16 (nearest even), sums exact, the row
         sum of the rounded p (what x86/attention_bf16_avx512.c computes);
  qk8    q.k from int8 codes: q 8-bit and k 7-bit per row (absmax scales),
         the u8 x s7 pairs of vpmaddubsw that cannot saturate; p v exact;
  all8   qk8 and p as 8-bit codes of [0, 1] times 7-bit v (per column).
Prints max and mean |error| over the output RMS (the kernel tests' measure).
Needs numpy (Debian: python3-numpy). Run: python3 tools/reference/attn_quant_error.py

Measured 2026-12-02: bf16 1.7-1.8e-2 max / 2.6-2.9e-3 mean at std 1 (the kernel
bench measures 1.8-2.1e-2 / 2.8e-3 for the real kernel); qk8 6.5-9.4e-2 /
1.0-1.2e-2, up to 0.52 max at std 3; all8 1.7-2.2e-1 / 1.9-2.4e-2: int8
products cost 4-10x bf16's error.
"""
import numpy as np


def bf16(x):
    u = np.asarray(x, np.float32).view(np.uint32)
    r = (u + 0x7FFF + ((u >> 16) & 1)) & 0xFFFF0000
    return r.astype(np.uint32).view(np.float32)


def quant_rows(x, qmax):
    s = np.abs(x).max(axis=1, keepdims=True) / qmax
    return np.round(x / s) * s


def attention(q, k, v, mode):
    d = q.shape[1]
    if mode == "bf16":
        s = bf16(q).astype(np.float64) @ bf16(k).astype(np.float64).T / np.sqrt(d)
    elif mode in ("qk8", "all8"):
        s = quant_rows(q, 127) @ quant_rows(k, 63).T / np.sqrt(d)
    else:
        s = q @ k.T / np.sqrt(d)
    p = np.exp(s - s.max(axis=1, keepdims=True))
    if mode == "bf16":
        p = bf16(p).astype(np.float64)
        return p @ bf16(v).astype(np.float64) / p.sum(axis=1, keepdims=True)
    if mode == "all8":
        p = np.round(p * 255) / 255
        return p @ quant_rows(v.T, 63).T / p.sum(axis=1, keepdims=True)
    return p @ v / p.sum(axis=1, keepdims=True)


def main():
    rng = np.random.default_rng(1)
    d = 64
    for n in (1374, 5496):
        for std in (1.0, 3.0):
            q = rng.standard_normal((256, d)) * std
            k = rng.standard_normal((n, d)) * std
            v = rng.standard_normal((n, d))
            ref = attention(q, k, v, "exact")
            rms = np.sqrt((ref ** 2).mean())
            row = []
            for mode in ("bf16", "qk8", "all8"):
                e = np.abs(attention(q, k, v, mode) - ref)
                row.append(f"{mode} max {e.max() / rms:.2e} mean {e.mean() / rms:.2e}")
            print(f"keys {n} std {std}: " + "; ".join(row))


if __name__ == "__main__":
    main()
