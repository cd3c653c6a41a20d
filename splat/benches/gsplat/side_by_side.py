"""gsplat beside metasplat on the same scene and camera (run on a machine with CUDA).

    python side_by_side.py EXPORT_DIR [repeats]

EXPORT_DIR is what `gpu_step ... EXPORT_DIR` wrote: scene.ply (INRIA layout), camera.json,
cpu_rgb.f32 (our CPU image) and ours.json (our timings). Prints one JSON line: gsplat's median
forward, forward+backward and training-step (with torch Adam) milliseconds, ours, the ratios
(our iterations per second as a fraction of gsplat's) and the PSNR of gsplat's image against
our CPU image. gsplat is not part of metasplat: it is installed for the measurement only.
"""

import json
import os
import sys
import time

import numpy as np


def read_ply(path):
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert "format binary_little_endian 1.0" in header, "expects a little-endian binary PLY"
    n = next(int(l.split()[2]) for l in header if l.startswith("element vertex"))
    props = [l.split() for l in header if l.startswith("property")]
    assert all(p[1] == "float" for p in props), "expects float properties"
    names = [p[2] for p in props]
    table = np.frombuffer(data[end:end + 4 * n * len(names)], dtype="<f4").reshape(n, len(names))
    col = {name: table[:, i] for i, name in enumerate(names)}
    rest = sorted((k for k in names if k.startswith("f_rest_")), key=lambda k: int(k[7:]))
    k = len(rest) // 3
    degree = int(round((k + 1) ** 0.5)) - 1
    sh = np.zeros((n, k + 1, 3), np.float32)
    sh[:, 0, :] = np.stack([col[f"f_dc_{c}"] for c in range(3)], 1)
    if k:
        r = np.stack([col[name] for name in rest], 1).reshape(n, 3, k)  # channel-major
        sh[:, 1:, :] = r.transpose(0, 2, 1)
    return {
        "means": np.stack([col["x"], col["y"], col["z"]], 1),
        "quats": np.stack([col[f"rot_{i}"] for i in range(4)], 1),  # w, x, y, z
        "log_scales": np.stack([col[f"scale_{i}"] for i in range(3)], 1),
        "logit_opacities": col["opacity"],
        "sh": sh,
        "degree": degree,
    }


def median_ms(repeats, f, sync):
    f()
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        f()
        sync()
        times.append((time.perf_counter() - start) * 1e3)
    return sorted(times)[len(times) // 2]


def main():
    folder = sys.argv[1]
    repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    scene = read_ply(os.path.join(folder, "scene.ply"))
    cam = json.load(open(os.path.join(folder, "camera.json")))
    ours = json.load(open(os.path.join(folder, "ours.json")))
    w, h = cam["width"], cam["height"]
    cpu_rgb = np.fromfile(os.path.join(folder, "cpu_rgb.f32"), dtype="<f4").reshape(h, w, 3)

    import torch
    from gsplat import rasterization

    dev = torch.device("cuda")
    t = {k: torch.tensor(v, device=dev) for k, v in scene.items() if k != "degree"}
    params = {k: v.clone().requires_grad_(True) for k, v in t.items()}
    view = torch.tensor(cam["world_to_camera"], dtype=torch.float32, device=dev)[None]
    K = torch.tensor(
        [[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1]],
        dtype=torch.float32,
        device=dev,
    )[None]

    def render(p):
        img, _, _ = rasterization(
            p["means"], p["quats"], torch.exp(p["log_scales"]), torch.sigmoid(p["logit_opacities"]),
            p["sh"], view, K, w, h, sh_degree=scene["degree"], near_plane=cam["near"],
            far_plane=cam["far"], eps2d=0.3, packed=False, rasterize_mode="classic",
        )
        return img[0]

    sync = torch.cuda.synchronize
    with torch.no_grad():
        img = render(t)
    mse = float(((img.clamp(0, 1).cpu().numpy() - cpu_rgb.clip(0, 1)) ** 2).mean())
    psnr = 10 * np.log10(1.0 / max(mse, 1e-20))

    def forward():
        with torch.no_grad():
            render(t)

    def forward_backward():
        (render(params) * 1e-3).sum().backward()

    opt = torch.optim.Adam(list(params.values()), lr=1e-3, eps=1e-15)

    def step():
        opt.zero_grad(set_to_none=True)
        (render(params) * 1e-3).sum().backward()
        opt.step()

    fwd = median_ms(repeats, forward, sync)
    fb = median_ms(repeats, forward_backward, sync)
    st = median_ms(repeats, step, sync)
    print(json.dumps({
        "splats": ours["splats"], "width": w, "height": h,
        "gpu": torch.cuda.get_device_name(),
        "gsplat_forward_ms": fwd, "gsplat_forward_backward_ms": fb, "gsplat_step_ms": st,
        "ours_gpu_forward_ms": ours["gpu_forward_ms"], "ours_gpu_step_ms": ours["gpu_step_ms"],
        "ours_cpu_forward_ms": ours["cpu_forward_ms"], "ours_cpu_step_ms": ours["cpu_step_ms"],
        "forward_rate_vs_gsplat": fwd / ours["gpu_forward_ms"],
        "step_rate_vs_gsplat": st / ours["gpu_step_ms"],
        # The measure. Ours is the resident step (forward, backward and Adam, the
        # gradients left on the GPU) against gsplat's forward+backward without an optimiser:
        # a lower bound on our rate.
        "forward_backward_rate_vs_gsplat": fb / ours["gpu_step_ms"],
        "psnr_gsplat_vs_our_cpu_image_db": psnr,
    }))


if __name__ == "__main__":
    main()
