#!/usr/bin/env python3
"""Widen a densefeat feature network (SPEC.md §8.4 safetensors) from C to 2C channels per layer, for
the capacity check of docs/table1/README.md ("A wider network on one room").

    python3 tools/paper/net2wider.py IN.safetensors OUT.safetensors [FRAC]

The old channels keep their function exactly: no new channel feeds an old one (those weights are
zero), so the first C output features equal IN's; every weight from or into a new channel is drawn
from N(0, (FRAC x the layer's old weight std)^2) (FRAC 0.1 by default, seed 0), biases 0. The output
has 2C feature channels, the first C unchanged and C small new ones. Layouts: convolutions
[C_out, C_in, 3, 3] with block k > 0's first convolution taking [previous block's C, image 3]
(concatenation order, SPEC §8), transposed convolutions [C_in, C_out, 5, 5]."""
import json, struct, sys
import numpy as np
src, dst = sys.argv[1], sys.argv[2]
frac = float(sys.argv[3]) if len(sys.argv) > 3 else 0.1
rng = np.random.default_rng(0)
raw = open(src, "rb").read()
n = struct.unpack("<Q", raw[:8])[0]
hdr = json.loads(raw[8:8 + n]); data = raw[8 + n:]
meta = hdr.pop("__metadata__")
C = int(meta["channels"])
t = {}
for k, v in hdr.items():
    a, b = v["data_offsets"]
    t[k] = np.frombuffer(data[a:b], np.float32).reshape(v["shape"]).copy()
out = {}
for k, w in t.items():
    if k.endswith("bias"):
        out[k] = np.concatenate([w, np.zeros(C, np.float32)])
        continue
    s = w.std() * frac
    o, i = w.shape[:2]
    if k.startswith("deconvs"):
        # ConvTranspose2d layout [C_in, C_out, 5, 5]
        nw = rng.normal(0, s, (2 * C, 2 * C) + w.shape[2:]).astype(np.float32)
        nw[:C, :C] = w
        nw[C:, :C] = 0  # new inputs do not feed old outputs
        out[k] = nw
        continue
    # conv [C_out, C_in, 3, 3]; inputs: C (prev) [+ 3 image] or 3 (block 0 conv1)
    extra = i - C if i >= C else 0
    if i == 3:
        nw = rng.normal(0, s, (2 * C, 3) + w.shape[2:]).astype(np.float32)
        nw[:C] = w
    else:
        nw = rng.normal(0, s, (2 * C, 2 * C + extra) + w.shape[2:]).astype(np.float32)
        nw[:C, :C] = w[:, :C]
        nw[:C, C:2 * C] = 0
        nw[:C, 2 * C:] = w[:, C:]
    out[k] = nw
meta = dict(meta); meta["channels"] = str(2 * C)
meta["provenance"] = f"net2wider x2 (frac {frac}) of {src}: " + meta.get("provenance", "")
hdr2 = {}; blobs = []; off = 0
for k in sorted(out):
    b = out[k].astype("<f4").tobytes()
    hdr2[k] = {"dtype": "F32", "shape": list(out[k].shape), "data_offsets": [off, off + len(b)]}
    blobs.append(b); off += len(b)
hdr2["__metadata__"] = meta
h = json.dumps(hdr2).encode(); h += b" " * ((8 - len(h) % 8) % 8)
open(dst, "wb").write(struct.pack("<Q", len(h)) + h + b"".join(blobs))
print("wrote", dst, "channels", 2 * C)
