# The scene of shared/notes/cpu-profile.md: means uniform in the frustum slab z in [3, 5] of a
# 504x378 camera with fx = fy = 403.2 (centred principal point), isotropic scales
# 0.55 (V/N)^(1/3) jittered by exp(U(-1/2, 1/2)), opacity U(0.1, 0.9), SH 0, seed 0.
import sys, numpy as np
n = int(sys.argv[1]); out = sys.argv[2]
rng = np.random.default_rng(0)
W, H, F = 504, 378, 403.2
ax, ay = (W / 2) / F, (H / 2) / F
# volume-uniform depth: density ~ z^2 on [3, 5]
u = rng.random(n); z = np.cbrt(27 + u * (125 - 27))
x = (rng.random(n) * 2 - 1) * ax * z; y = (rng.random(n) * 2 - 1) * ay * z
V = 4 * ax * ay * (125 - 27) / 3
s = 0.55 * (V / n) ** (1 / 3) * np.exp(rng.random(n) - 0.5)
op = rng.uniform(0.1, 0.9, n)
col = rng.random((n, 3))
C0 = 0.28209479177387814
dc = (col - 0.5) / C0
props = ["x","y","z","nx","ny","nz","f_dc_0","f_dc_1","f_dc_2","opacity","scale_0","scale_1","scale_2","rot_0","rot_1","rot_2","rot_3"]
data = np.zeros((n, len(props)), np.float32)
data[:,0], data[:,1], data[:,2] = x, y, z
data[:,6:9] = dc
data[:,9] = np.log(op / (1 - op))
data[:,10:13] = np.log(s)[:,None]
data[:,13] = 1.0
with open(out, "wb") as f:
    f.write(("ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % n).encode())
    for p in props: f.write(("property float %s\n" % p).encode())
    f.write(b"end_header\n"); f.write(data.tobytes())
print("wrote", out, "V", V, "scale", 0.55 * (V / n) ** (1 / 3))
