"""gguf_read.py - reads the f32 tensors of one of our GGUF files back into a PyTorch
state dict (names as f4d-convert wrote them, i.e. the training names), so that training
can resume from the shipped weights when no checkpoint is at hand."""
import struct

import numpy as np
import torch

_SCALAR = {0: "<B", 1: "<b", 2: "<H", 3: "<h", 4: "<I", 5: "<i", 6: "<f", 7: "<?", 10: "<Q", 11: "<q", 12: "<d"}


class _Rd:
    def __init__(self, buf):
        self.b, self.o = buf, 0

    def un(self, fmt):
        v = struct.unpack_from(fmt, self.b, self.o)
        self.o += struct.calcsize(fmt)
        return v[0]

    def str(self):
        n = self.un("<Q")
        s = self.b[self.o:self.o + n].decode()
        self.o += n
        return s

    def val(self, t):
        if t == 8:
            return self.str()
        if t == 9:
            it, n = self.un("<I"), self.un("<Q")
            return [self.val(it) for _ in range(n)]
        if t not in _SCALAR:
            raise ValueError(f"gguf: unknown value type {t}")
        return self.un(_SCALAR[t])


def read(path):
    """-> (metadata dict, {name: float32 tensor}); refuses non-f32 tensors by name."""
    with open(path, "rb") as f:
        buf = f.read()
    r = _Rd(buf)
    if r.un("<I") != 0x46554747:
        raise ValueError(f"{path}: not a GGUF file")
    ver, nt, nkv = r.un("<I"), r.un("<Q"), r.un("<Q")
    if ver != 3:
        raise ValueError(f"{path}: GGUF version {ver}, expected 3")
    meta = {}
    for _ in range(nkv):
        k = r.str()
        meta[k] = r.val(r.un("<I"))
    infos = []
    for _ in range(nt):
        name = r.str()
        nd = r.un("<I")
        dims = [r.un("<Q") for _ in range(nd)]
        typ, off = r.un("<I"), r.un("<Q")
        infos.append((name, dims, typ, off))
    align = int(meta.get("general.alignment", 32))
    base = (r.o + align - 1) // align * align
    sd = {}
    for name, dims, typ, off in infos:
        if typ != 0:
            raise ValueError(f"{path}: tensor '{name}' is not f32 (type {typ})")
        n = int(np.prod(dims)) if dims else 1
        a = np.frombuffer(buf, np.float32, n, base + off)
        sd[name] = torch.from_numpy(a.copy()).reshape(list(reversed(dims)))
    return meta, sd
