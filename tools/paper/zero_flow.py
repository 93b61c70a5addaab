#!/usr/bin/env python3
"""The inverse depth of zero flow: for keyframe pixels of a DeepVideoMVS-layout sequence (poses.txt
camera-to-world 4x4 per line, K.txt), the hypothesis rho at which the pixel's mean image motion over
all other frames is smallest. A feature that carries its image position (a position code, vignetting)
matches best there. Used in docs/table1/README.md ("The blank wall's cost curves").

    python3 tools/paper/zero_flow.py SEQUENCE KEYFRAME "x,y;x,y;..." [RHO_MAX]
"""
import sys

import numpy as np


def main(argv):
    if len(argv) < 3:
        sys.exit(__doc__)
    seq, kf = argv[0], int(argv[1])
    pixels = [tuple(int(v) for v in p.split(",")) for p in argv[2].split(";")]
    rho_max = float(argv[3]) if len(argv) > 3 else 2.5
    poses = np.loadtxt(f"{seq}/poses.txt").reshape(-1, 4, 4)
    k = np.loadtxt(f"{seq}/K.txt")
    if not 0 <= kf < len(poses):
        sys.exit(f"zero_flow.py: keyframe {kf}: the sequence has {len(poses)} frames")
    k_inv = np.linalg.inv(k)
    others = [np.linalg.inv(p) for j, p in enumerate(poses) if j != kf]
    rhos = np.linspace(0.01, rho_max, 250)
    for x, y in pixels:
        ray = k_inv @ np.array([x, y, 1.0])
        flows = []
        for rho in rhos:
            world = poses[kf] @ np.append(ray / rho, 1.0)
            motion = 0.0
            for w2c in others:
                c = w2c @ world
                u = k @ c[:3]
                motion += np.hypot(u[0] / u[2] - x, u[1] / u[2] - y)
            flows.append(motion / len(others))
        i = int(np.argmin(flows))
        print(f"pixel ({x}, {y}): zero flow at rho {rhos[i]:.3f} 1/m (mean motion {flows[i]:.1f} px; "
              f"at rho {rho_max}: {flows[-1]:.1f} px)")


if __name__ == "__main__":
    main(sys.argv[1:])
