#!/usr/bin/env python3
"""Renders a scene of this folder with Mitsuba 3's volumetric path tracers, timed, for `bench`.

  ../shared/bench/peers/.venv/bin/python scenes/materials/mitsuba_peer.py glass-smooth \
      --spp 16,64,256,1024,4096 --csv glass.csv
  ../shared/bench/peers/.venv/bin/python scenes/materials/mitsuba_peer.py subsurface --check 2048
  ../shared/bench/peers/.venv/bin/python scenes/materials/mitsuba_peer.py subsurface-matched \
      --ref /tmp/subsurface-matched-48.exr --chunk 2048 --minutes 10

The scene is built from the repo's glTF (`<scene>.gltf`, `<scene>.settings.json`), as the
references `ref/<scene>-48.exr` were: floor and light Lambertian (the light one-sided), the sky a
constant emitter; a sphere with `KHR_materials_transmission` becomes a `dielectric` (roughness 0)
or `roughdielectric` (GGX, alpha = roughness^2) from `ext_ior` 1 to its `KHR_materials_ior` (an
index-matched boundary, ior 1, becomes by `--boundary` a `dielectric` of ior 1.0001, which paths
cross without light sampled through it, as in ours, or a `null` surface, through which
`volpathmis` samples the light from inside the medium), with a `homogeneous` medium inside:
sigma_t = -ln(attenuationColor) / attenuationDistance per channel, albedo 0 for glass, or the
single-scattering albedo that `KHR_materials_volume_scatter` gives for its `multiscatterColor`
(`common::scene::single_scatter_albedo`), and a Henyey-Greenstein phase function of
g = `scatterAnisotropy`. The integrator is `volpath` for absorbing media and
`volpathmis` for scattering ones (`volpath` leaves fireflies in the red channel of the subsurface
scene), `max_depth` = ours + 1 (Mitsuba's depth 1 is an emitter seen directly, ours 0),
Russian roulette from depth 5 (`--rr-depth`: a reference of a scene with a scattering medium
wants it off, e.g. 5000; `volpathmis` biases light reached after a bounce past rr_depth, see
docs/perf/materials.md), `llvm_ad_rgb`, box filter, independent sampler.

Each run builds the scene and renders it (`seconds` = load + render, as `../shared/bench/peers/
run.py` counts them: no Python import, no image writing) after one untimed warm-up render that
fills Dr.Jit's kernel cache. The CSV has run.py's columns (which `bench --peer-csv` reads), the
relative MSE against `ref/<scene>-<width>.exr` computed as `bench` does, plus `median_relmse`,
the median over pixels of each pixel's relative squared error. `--check SPP` renders once and
prints the image's mean over the reference's per channel instead.

`--ref OUT.exr` renders a reference instead: chunks of `--chunk` spp with seeds `--seed`,
`--seed` + 1, ... for `--minutes` of wall clock, the chunks alternating between two halves; after
every chunk it writes their average to OUT.exr, the halves' averages beside it
(`OUT.half-a.exr`, `OUT.half-b.exr`) and `OUT.ref.json` (stem without `.exr`) with the fields of
`ref/*.ref.json`: renderer, spp, chunks and the reference's own noise from the two halves
(`noise_relmse_est`, `noise_rmse_est`: the mean squared half difference times
n_a n_b / (n_a + n_b)^2, the variance of the whole average).
"""
import argparse
import csv
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PEERS = HERE.parent.parent.parent / "shared" / "bench" / "peers"
sys.path.insert(0, str(PEERS))
import gltf_load  # noqa: E402
from exrio import read_exr  # noqa: E402

COLUMNS = ["renderer", "version", "variant", "scene", "spp", "seconds", "rmse", "relmse", "mae",
           "t_load", "t_render", "t_import", "spp_done", "threads", "width", "height", "us_per_sample",
           "rays_per_sec", "seed", "peer", "cpu_seconds", "load1", "median_relmse"]
VARIANT = "llvm_ad_rgb"


def single_scatter_albedo(multiscatter):
    """KHR_materials_volume_scatter's inversion of a multiple-scattering colour (Kulla and Conty
    2017), as `common::scene::single_scatter_albedo` computes it."""
    a = min(max(multiscatter, 0.0), 1.0)
    if a in (0.0, 1.0):
        return a
    s = 4.09712 + 4.20863 * a - math.sqrt(9.59217 + 41.6808 * a + 17.7126 * a * a)
    return min(max(1.0 - s * s, 0.0), 1.0)


def metrics(img, ref):
    """RMSE, relative MSE (+0.01 in the denominator, non-finite values as 0) and the median pixel's
    relative squared error, as `bench`'s `metrics` and `median_rel_error`."""
    img = np.asarray(img, np.float64)[..., :3]
    ref = np.asarray(ref, np.float64)[..., :3]
    img = np.where(np.isfinite(img), img, 0.0)
    d = img - ref
    rel = d * d / (ref * ref + 0.01)
    return (float(np.sqrt(np.mean(d * d))), float(np.mean(rel)), float(np.mean(np.abs(d))),
            float(np.median(rel.mean(axis=-1))))


def rgb(value):
    return {"type": "rgb", "value": [float(c) for c in value]}


# Mitsuba's `dielectric` needs int_ior != ext_ior: an index-matched boundary is the nearest one.
NEAR_MATCHED_IOR = 1.0001


# Whether a rough dielectric is divided by its own single-scattering albedo, as ours is
# (`--single-scattering` turns it off: Mitsuba's `roughdielectric` as it is).
COMPENSATED = True


def register_compensated(mi, dr):
    """Registers `compensated`: Mitsuba's `roughdielectric` (GGX) with its eval and sample weight
    divided by E(|cos wi|), the single-scattering albedo of that BSDF itself from the side `wi`
    is on, counted as energy (a refracted weight times bs.eta², undoing radiance's 1 / eta²):
    Cycles' energy compensation for glass, which ours applies (`bsdf/dielectric.rs`). E is
    estimated here from Mitsuba's own samples (2^16 at each of 128 cosines per side, read
    linearly between them), independently of our tables."""
    n_mu, n_samples = 128, 1 << 16

    class Compensated(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.inner = mi.load_dict({"type": "roughdielectric", "distribution": "ggx",
                                       "alpha": props["alpha"], "int_ior": props["int_ior"],
                                       "ext_ior": 1.0})
            self.m_flags = self.inner.m_flags
            self.m_components = [self.inner.flags(i) for i in range(self.inner.component_count())]
            table = []
            for side in (1.0, -1.0):
                for k in range(n_mu):
                    mu = (k + 0.5) / n_mu
                    si = dr.zeros(mi.SurfaceInteraction3f, n_samples)
                    si.wi = mi.Vector3f(math.sqrt(1.0 - mu * mu), 0.0, side * mu)
                    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
                    rng = mi.PCG32(size=n_samples, initstate=mi.UInt64(1 + 2 * k + (side < 0)))
                    bs, weight = self.inner.sample(mi.BSDFContext(), si, rng.next_float32(),
                                                   mi.Point2f(rng.next_float32(),
                                                              rng.next_float32()), True)
                    energy = weight[0] * dr.square(bs.eta)
                    table.append(float(dr.mean(dr.select(dr.isfinite(energy), energy, 0.0))[0]))
            self.table = mi.Float(table)

        def albedo(self, si):
            cos = mi.Frame3f.cos_theta(si.wi)
            x = dr.clip(dr.abs(cos) * n_mu - 0.5, 0.0, n_mu - 1.0)
            i = dr.minimum(mi.UInt32(x), n_mu - 2)
            f = x - mi.Float(i)
            base = dr.select(cos >= 0.0, 0, n_mu) + i
            a = dr.gather(mi.Float, self.table, base)
            b = dr.gather(mi.Float, self.table, base + 1)
            return a + (b - a) * f

        def sample(self, ctx, si, sample1, sample2, active):
            bs, weight = self.inner.sample(ctx, si, sample1, sample2, active)
            return bs, weight / self.albedo(si)

        def eval(self, ctx, si, wo, active):
            return self.inner.eval(ctx, si, wo, active) / self.albedo(si)

        def pdf(self, ctx, si, wo, active):
            return self.inner.pdf(ctx, si, wo, active)

        def eval_pdf(self, ctx, si, wo, active):
            value, pdf = self.inner.eval_pdf(ctx, si, wo, active)
            return value / self.albedo(si), pdf

        def traverse(self, cb):
            pass

        def to_string(self):
            return "Compensated[%s]" % self.inner

    mi.register_bsdf("compensated", lambda props: Compensated(props))


def surface(mi, material, boundary):
    """The BSDF and (for a transmitting volume) the interior medium of a glTF material; `boundary`
    (`dielectric` or `null`) is what an ior-1 boundary becomes."""
    pbr = material.get("pbrMetallicRoughness", {})
    ext = material.get("extensions", {})
    if ext.get("KHR_materials_transmission", {}).get("transmissionFactor", 0.0) == 1.0:
        ior = ext.get("KHR_materials_ior", {}).get("ior", 1.5)
        roughness = pbr.get("roughnessFactor", 1.0)
        if ior == 1.0 and boundary == "null":
            bsdf = {"type": "null"}
        elif ior == 1.0:
            assert roughness == 0.0, material["name"]
            bsdf = {"type": "dielectric", "int_ior": NEAR_MATCHED_IOR, "ext_ior": 1.0}
        elif roughness == 0.0:
            bsdf = {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0}
        else:
            bsdf = {"type": "roughdielectric", "distribution": "ggx", "alpha": roughness**2,
                    "int_ior": ior, "ext_ior": 1.0}
            if COMPENSATED:
                bsdf = {"type": "compensated", "alpha": roughness**2, "int_ior": ior}
        volume = ext.get("KHR_materials_volume")
        if volume is None:
            return mi.load_dict(bsdf), None, False
        distance = volume.get("attenuationDistance", math.inf)
        color = volume.get("attenuationColor", [1.0, 1.0, 1.0])
        sigma_t = [-math.log(c) / distance for c in color]
        scatter = ext.get("KHR_materials_volume_scatter")
        albedo = [0.0, 0.0, 0.0]
        phase = {"type": "hg", "g": 0.0}
        if scatter is not None:
            albedo = [single_scatter_albedo(c) for c in scatter.get("multiscatterColor", [0, 0, 0])]
            phase = {"type": "hg", "g": scatter.get("scatterAnisotropy", 0.0)}
        # An RGB parameter is a reflectance in [0, 1]: sigma_t goes in as a colour times a scale.
        scale = max(sigma_t)
        medium = {"type": "homogeneous", "sigma_t": rgb([s / scale for s in sigma_t]),
                  "scale": scale, "albedo": rgb(albedo), "phase": phase}
        return mi.load_dict(bsdf), mi.load_dict(medium), max(albedo) > 0.0
    # Every other surface of these scenes is Lambertian (KHR_materials_specular factor 0).
    assert ext.get("KHR_materials_specular", {}).get("specularFactor") == 0.0, material["name"]
    bsdf = {"type": "diffuse", "reflectance": rgb(pbr.get("baseColorFactor", [1, 1, 1])[:3])}
    if material.get("doubleSided", False):
        bsdf = {"type": "twosided", "bsdf": bsdf}
    return mi.load_dict(bsdf), None, False


def build(mi, path, width, height, spp, seed, boundary="dielectric", rr_depth=5):
    """The Mitsuba scene of a glTF file of this folder, with the integrator its media call for
    (Russian roulette from `rr_depth`; one beyond `max_depth` turns it off)."""
    scene = gltf_load.load(path)
    gltf = json.loads(Path(path).read_text())
    surfaces = [surface(mi, m, boundary) for m in gltf["materials"]]
    scatters = any(s[2] for s in surfaces)
    max_depth = scene.settings["max_depth"] + 1
    camera = scene.camera
    d = {
        "type": "scene",
        "integrator": {"type": "volpathmis" if scatters else "volpath", "max_depth": max_depth,
                       "rr_depth": rr_depth, "hide_emitters": False},
        "sensor": {
            "type": "perspective", "fov": math.degrees(camera.yfov), "fov_axis": "y",
            "near_clip": 1e-3, "far_clip": 1e5,
            "to_world": mi.ScalarTransform4f().look_at(origin=camera.origin.tolist(),
                                                       target=(camera.origin + camera.forward).tolist(),
                                                       up=camera.up.tolist()),
            "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                     "pixel_format": "rgb", "component_format": "float32"},
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
        },
        "sky": {"type": "constant", "radiance": rgb(scene.settings["environment"]["color"])},
    }
    for k, mesh in enumerate(scene.meshes):
        material = scene.materials[mesh.material]
        bsdf, interior, _ = surfaces[mesh.material]
        props = mi.Properties()
        props["bsdf"] = bsdf
        if interior is not None:
            props["interior"] = interior
        if material.is_emissive:  # Mitsuba's area emitters are one-sided, as the glTF light is.
            props["emitter"] = mi.load_dict({"type": "area", "radiance": rgb(material.emission)})
        shape = mi.Mesh(mesh.name, len(mesh.positions), len(mesh.indices), props=props,
                        has_vertex_normals=mesh.normals is not None)
        params = mi.traverse(shape)
        params["vertex_positions"] = type(params["vertex_positions"])(mesh.positions.ravel())
        params["faces"] = type(params["faces"])(mesh.indices.ravel())
        if mesh.normals is not None:
            params["vertex_normals"] = type(params["vertex_normals"])(mesh.normals.ravel())
        params.update()
        d[f"mesh{k}"] = shape
    return mi.load_dict(d), d["integrator"]


def render(mi, path, width, height, spp, seed, boundary="dielectric", rr_depth=5):
    """Loads and renders; returns the image, the load and render seconds and the integrator."""
    start = time.perf_counter()
    scene, integrator = build(mi, path, width, height, spp, seed, boundary, rr_depth)
    loaded = time.perf_counter()
    image = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)
    return image, loaded - start, time.perf_counter() - loaded, integrator


def make_reference(mi, a, path):
    """Renders the chunks of a reference into two halves until `--minutes` would be passed."""
    from exrio import write_exr
    out = Path(a.ref)
    stem = out.with_suffix("")
    scene, integrator = build(mi, path, a.size, a.size, a.chunk, a.seed, a.boundary, a.rr_depth)
    ior = [m.get("extensions", {}).get("KHR_materials_ior", {}).get("ior")
           for m in json.loads(path.read_text())["materials"]]
    boundary = None
    if 1.0 in ior:
        boundary = (f"dielectric int_ior={NEAR_MATCHED_IOR} ext_ior=1" if a.boundary == "dielectric"
                    else "null")
    sums, counts = [0.0, 0.0], [0, 0]
    t_start, c_start = time.perf_counter(), time.process_time()
    last = 0.0
    k = 0
    while k == 0 or time.perf_counter() - t_start + last <= a.minutes * 60:
        t0 = time.perf_counter()
        image = np.array(mi.render(scene, spp=a.chunk, seed=a.seed + k), dtype=np.float64)[..., :3]
        last = time.perf_counter() - t0
        sums[k % 2] = sums[k % 2] + image * a.chunk
        counts[k % 2] += a.chunk
        k += 1
        total = counts[0] + counts[1]
        ref = (sums[0] + sums[1]) / total
        write_exr(out, ref)
        meta = {"scene": a.scene, "peer": f"mitsuba:{VARIANT}", "renderer": "mitsuba",
                "version": mi.__version__, "variant": VARIANT, "spp": total, "chunks": k,
                "chunk_spp": a.chunk, "seeds": f"{a.seed}..{a.seed + k - 1}",
                "wall_seconds": round(time.perf_counter() - t_start, 1),
                "cpu_seconds": round(time.process_time() - c_start, 1),
                "config": f"{integrator['type']} max_depth={integrator['max_depth']} "
                          f"rr_depth={integrator['rr_depth']}, sampler=independent, rfilter=box(r=0.5)",
                "render_args": f"scenes/materials/mitsuba_peer.py {a.scene} --ref {out.name} "
                               f"--boundary {a.boundary} --rr-depth {a.rr_depth} --chunk {a.chunk} "
                               f"--seed {a.seed} "
                               f"--size {a.size} --threads {a.threads}",
                "width": a.size, "height": a.size}
        if boundary:
            meta["boundary"] = boundary
        if counts[1]:
            half_a, half_b = sums[0] / counts[0], sums[1] / counts[1]
            write_exr(f"{stem}.half-a.exr", half_a)
            write_exr(f"{stem}.half-b.exr", half_b)
            d = half_a - half_b
            share = counts[0] * counts[1] / total**2  # Var(ref) = Var(d) n_a n_b / n^2
            meta["half_spp"] = counts
            meta["noise_relmse_est"] = float(np.mean(d * d / (ref * ref + 0.01)) * share)
            meta["noise_rmse_est"] = float(np.sqrt(np.mean(d * d) * share))
        Path(f"{stem}.ref.json").write_text(json.dumps(meta, indent=1) + "\n")
        print(f"chunk {k}: {total} spp, {meta['wall_seconds']} s, noise relmse est "
              f"{meta.get('noise_relmse_est', float('nan')):.3g}", flush=True)
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", help="a scene of this folder, e.g. glass-smooth")
    ap.add_argument("--spp", default="16,64,256,1024", help="sample counts of the timed renders")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1, help="the first run's seed; each run adds one")
    ap.add_argument("--size", type=int, default=48, help="width and height (the reference's)")
    ap.add_argument("--csv", help="CSV to write (run.py's columns)")
    ap.add_argument("--check", type=int, metavar="SPP",
                    help="render once at SPP and print mean ratios against the reference")
    ap.add_argument("--boundary", choices=["dielectric", "null"], default="dielectric",
                    help=f"an ior-1 boundary as a dielectric of ior {NEAR_MATCHED_IOR} (no light "
                         "sampled through it, as ours) or a null surface")
    ap.add_argument("--rr-depth", type=int, default=5,
                    help="Mitsuba's rr_depth (default 5); one beyond max_depth (e.g. 5000) turns "
                         "Russian roulette off, which a reference of a scene with media needs: "
                         "volpathmis puts the survival probability into the MIS weight of an emitter "
                         "that BSDF or phase sampling hits, not into that of the light sample, and so "
                         "darkens light reached after a bounce at depth > rr_depth "
                         "(docs/perf/materials.md)")
    ap.add_argument("--single-scattering", action="store_true",
                    help="a rough dielectric as Mitsuba's roughdielectric, without the energy "
                         "compensation ours applies (the references before it)")
    ap.add_argument("--ref", metavar="OUT.exr", help="render a reference in chunks to OUT.exr")
    ap.add_argument("--chunk", type=int, default=2048, help="spp of a reference's chunk")
    ap.add_argument("--minutes", type=float, default=10.0, help="wall clock of a reference")
    a = ap.parse_args()

    t0 = time.perf_counter()
    import drjit as dr
    import mitsuba as mi
    mi.set_variant(VARIANT)
    dr.set_thread_count(a.threads)
    global COMPENSATED
    COMPENSATED = not a.single_scattering
    register_compensated(mi, dr)
    t_import = time.perf_counter() - t0
    path = HERE / f"{a.scene}.gltf"
    if a.ref:
        return make_reference(mi, a, path)
    ref = read_exr(HERE / "ref" / f"{a.scene}-{a.size}.exr")
    assert ref.shape[:2] == (a.size, a.size), ref.shape

    if a.check:
        image, t_load, t_render, integrator = render(mi, path, a.size, a.size, a.check, a.seed,
                                                      a.boundary, a.rr_depth)
        ratio = image.reshape(-1, 3).mean(axis=0) / ref.reshape(-1, 3).mean(axis=0)
        rmse, relmse, _, median = metrics(image, ref)
        print(f"{a.scene}: {integrator['type']} max_depth {integrator['max_depth']}, {a.check} spp in "
              f"{t_load + t_render:.1f} s; mean ratio to the reference (R, G, B) "
              f"{', '.join(f'{r:.5f}' for r in ratio)}; relmse {relmse:.3e}, median {median:.3e}")
        return 0

    render(mi, path, a.size, a.size, 4, 0, a.boundary, a.rr_depth)  # Warm-up: Dr.Jit's kernel cache and the page cache.
    rows = []
    print("scene,spp,seconds,samples_per_s,rmse,relmse,median_relmse,load1")
    for k, spp in enumerate(int(s) for s in a.spp.split(",")):
        seed = a.seed + k
        c0 = time.process_time()
        image, t_load, t_render, integrator = render(mi, path, a.size, a.size, spp, seed, a.boundary,
                                                      a.rr_depth)
        cpu = time.process_time() - c0
        rmse, relmse, mae, median = metrics(image, ref)
        load1 = os.getloadavg()[0]
        seconds = t_load + t_render
        samples = a.size * a.size * spp
        print(f"{a.scene},{spp},{seconds:.4f},{samples / t_render:.0f},{rmse:.6f},{relmse:.6e},"
              f"{median:.6e},{load1:.2f}", flush=True)
        rows.append({"renderer": "mitsuba", "version": mi.__version__, "variant": VARIANT,
                     "scene": a.scene, "spp": spp, "seconds": seconds, "rmse": rmse, "relmse": relmse,
                     "mae": mae, "t_load": t_load, "t_render": t_render, "t_import": t_import,
                     "spp_done": spp, "threads": a.threads, "width": a.size, "height": a.size,
                     "us_per_sample": t_render / samples * 1e6, "rays_per_sec": "", "seed": seed,
                     "peer": f"mitsuba:{integrator['type']}", "cpu_seconds": cpu, "load1": load1,
                     "median_relmse": median})
    if a.csv:
        with open(a.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS)
            w.writeheader()
            for r in rows:
                w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
        print(f"wrote {a.csv} ({len(rows)} rows)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
