#!/usr/bin/env python3
"""Compares an image of a scene of this folder with a reference by region of the sphere, in z-scores.

  ../shared/bench/peers/.venv/bin/python scenes/materials/agreement.py subsurface-matched \
      IMAGE.exr REF.exr [--block 16]

IMAGE is our EXR (its `variance` part gives each pixel's variance of the mean; several joined by
commas are merged by their `samples`) or a Mitsuba reference written by `mitsuba_peer.py --ref`; REF is such a reference. A reference's per-pixel
variance comes from its two halves (`REF.half-a.exr`, `REF.half-b.exr`, spp from `REF.ref.json`):
(a - b)^2 n_a n_b / n^2, unbiased per pixel, so its sums over a region are good estimates. For
the sphere (the mesh whose material has `KHR_materials_transmission`), the regions are its disc
two pixels inside its outline, a band two pixels either side of the outline, and the rest of the
image, from a ray-sphere test of 8x8 points per pixel. Each region's mean ratio and
z = (mean - reference mean) / sqrt(sum of both variances) / n are printed per channel, then the
whole image's, and the z of square blocks (mean z^2, about 1 for noise alone, and the largest |z|).
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PEERS = HERE.parent.parent.parent / "shared" / "bench" / "peers"
sys.path.insert(0, str(PEERS))
import gltf_load  # noqa: E402


def read_parts(path):
    """The R, G, B channels of each part of an EXR by the part's name, (H, W, 3) float64, and
    the `samples` channel (None in a file without one)."""
    import OpenEXR
    with OpenEXR.File(str(path), separate_channels=True) as f:
        parts = {p.name(): {k.split(".")[-1]: v.pixels for k, v in p.channels.items()} for p in f.parts}
    samples = next((ch["samples"] for ch in parts.values() if "samples" in ch), None)
    return {name: np.stack([ch[c] for c in "RGB"], -1).astype(np.float64)
            for name, ch in parts.items()}, samples


def read(path):
    """(mean, variance of the mean) per pixel and channel, both (H, W, 3) float64. Our EXRs
    joined by commas are merged by their `samples` counts."""
    if "," in str(path):
        runs = [read_parts(p) for p in str(path).split(",")]
        n = [s[..., None].astype(np.float64) for _, s in runs]
        total = sum(n)
        mean = sum(k * next(iter(parts.values())) for k, (parts, _) in zip(n, runs)) / total
        var = sum(k * k * parts["variance"] for k, (parts, _) in zip(n, runs)) / (total * total)
        return mean, var
    path = Path(path)
    parts, _ = read_parts(path)
    mean = next(iter(parts.values()))
    if "variance" in parts:
        return mean, parts["variance"]
    stem = path.with_suffix("")
    meta = json.loads(Path(f"{stem}.ref.json").read_text())
    n_a, n_b = meta["half_spp"]
    halves = [next(iter(read_parts(f"{stem}.half-{h}.exr")[0].values())) for h in "ab"]
    d = halves[0] - halves[1]
    return mean, d * d * n_a * n_b / (n_a + n_b) ** 2


def sphere_regions(scene_path, width, height, margin=2, sub=8):
    """Boolean masks (inside, band, rest) of the sphere's projected disc."""
    scene = gltf_load.load(scene_path)
    gltf = json.loads(Path(scene_path).read_text())
    transmits = [i for i, m in enumerate(gltf["materials"])
                 if "KHR_materials_transmission" in m.get("extensions", {})]
    mesh = next(m for m in scene.meshes if m.material in transmits)
    lo, hi = mesh.positions.min(axis=0).astype(np.float64), mesh.positions.max(axis=0)
    center, radius = (lo + hi) / 2, (hi - lo).max() / 2  # (a UV sphere's vertex mean is not)
    cam = scene.camera
    forward, up = cam.forward, cam.up
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    t = np.tan(cam.yfov / 2)
    s = (np.arange(sub) + 0.5) / sub
    xs = (np.arange(width)[:, None] + s[None, :]).ravel()
    ys = (np.arange(height)[:, None] + s[None, :]).ravel()
    px = (xs / width * 2 - 1) * t * width / height
    py = (1 - ys / height * 2) * t
    d = forward + px[None, :, None] * right + py[:, None, None] * up
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    oc = center - cam.origin
    along = d @ oc
    miss2 = oc @ oc - along * along
    hit = (miss2 < radius * radius) & (along > 0)
    cover = hit.reshape(height, sub, width, sub).mean(axis=(1, 3))
    full, partial = cover == 1.0, (cover > 0) & (cover < 1)

    def grow(mask, n):
        out = mask.copy()
        for _ in range(n):
            g = out.copy()
            g[1:] |= out[:-1]
            g[:-1] |= out[1:]
            g[:, 1:] |= out[:, :-1]
            g[:, :-1] |= out[:, 1:]
            out = g
        return out

    # Where the outline runs along a pixel edge no pixel is partly covered: such neighbours count too.
    empty = cover == 0.0
    edge = partial | (full & grow(empty, 1)) | (empty & grow(full, 1))
    band = grow(edge, margin)
    inside = full & ~band
    return inside, band, ~inside & ~band


def z_of(d, v):
    """d / sqrt(v); 0 where neither image has noise (the sky, which differs by its rounding)."""
    return np.where(v > 0, d / np.sqrt(np.where(v > 0, v, 1)), 0.0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("image")
    ap.add_argument("reference")
    ap.add_argument("--block", type=int, default=16)
    a = ap.parse_args()
    img, img_var = read(a.image)
    ref, ref_var = read(a.reference)
    h, w, _ = ref.shape
    inside, band, rest = sphere_regions(HERE / f"{a.scene}.gltf", w, h)
    var = img_var + ref_var
    names = "+".join(Path(f).name for f in a.image.split(","))
    print(f"{names} against {Path(a.reference).name}")
    print("region          pixels  ratio R, G, B                 z R, G, B")
    for name, mask in [("sphere inside", inside), ("silhouette band", band), ("rest", rest),
                       ("whole image", np.ones((h, w), bool))]:
        n = mask.sum()
        ratio = img[mask].mean(0) / ref[mask].mean(0)
        z = z_of((img[mask] - ref[mask]).sum(0), var[mask].sum(0))
        print(f"{name:15} {n:6d}  {', '.join(f'{r:.5f}' for r in ratio)}   "
              f"{', '.join(f'{x:+.2f}' for x in z)}")
    b = a.block
    d = (img - ref)[: h - h % b, : w - w % b].reshape(h // b, b, w // b, b, 3).sum((1, 3))
    v = var[: h - h % b, : w - w % b].reshape(h // b, b, w // b, b, 3).sum((1, 3))
    zb = z_of(d, v)
    i = np.unravel_index(np.abs(zb).argmax(), zb.shape)
    print(f"{b}x{b} blocks ({zb.size} z): mean z^2 {np.mean(zb * zb):.2f}, largest |z| "
          f"{abs(zb[i]):.2f} (block row {i[0]}, column {i[1]}, channel {'RGB'[i[2]]})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
