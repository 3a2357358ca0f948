#!/usr/bin/env python3
"""Renders the mirror caustic of `bench --caustic` with LuxCore, timed, for `bench --peer-csv`.

  cargo run --release -p coordinator --bin bench -- --caustic --caustic-reference /tmp/caustic.exr
  ../shared/bench/peers/.venv/bin/python scenes/caustic/luxcore_peer.py --ref /tmp/caustic.exr \
      --csv caustic-luxcore.csv
  cargo run --release -p coordinator --bin bench -- --caustic --peer-csv caustic-luxcore.csv

The scene is `worker::test_scenes::MirrorCaustic` with the bench's light (half side 0.125,
radiance 7.5 / 0.125²), built here from the same numbers: a `matte` floor of albedo 0.5 (the
square |x|, |z| <= 3 at y = 0), a `mirror` of reflectance 1 facing down (the same square at
y = 1; ours is GGX at alpha 1e-3, which moves the floor's light by about 1e-5), a black `matte`
light facing up with one-sided emission (|x|, |z| <= 0.125 at y = 0.1), and a pinhole at
(1.2, 0.5, 0) looking down, image up -z, 90 degrees: 64x64, box filter of one pixel, as ours.

Engines (`--engines`): `BIDIRCPU`, LuxCore's bidirectional path tracer (light tracing, light
samples and connections weighted by MIS), with eye depth 3 and light depth 2. LuxCore caps the
two subpaths' depths separately, not their sum, but here that is our `max_depth` 2 exactly: the
only paths that carry light are camera, floor, mirror, light (the light subpath light, mirror,
floor connected to the camera; the eye subpath floor, mirror, light), and every longer path
this allows, through a second floor vertex, connects floor to floor (coplanar: zero), floor to
the mirror (specular: never connected) or floor to the light's black back. `PATHCPU`, its path
tracer, with `path.pathdepth.total` 3 (LuxCore's depth 2 leaves the floor black: it counts the
emitter's hit; 3 is within 0.25% of the closed form at 4096 spp, `--check 4096`). Russian roulette starts past these depths; sampler `SOBOL` (`RANDOM` for
BIDIRCPU, whose light paths the Sobol sampler does not stratify: `--sampler`).

Each run parses the scene and renders it (`seconds` = load + render, as `../shared/bench/peers/
run.py` counts them) after one untimed warm-up render. The CSV has run.py's columns (which
`bench --peer-csv` reads; scene `mirror-caustic`) and the relative MSE against the closed form
computed as `bench` does. `--check SPP` renders once per engine and prints the image mean over
the closed form's and the relative MSE instead.
"""

import argparse
import csv
import os
import time

import OpenEXR  # before pyluxcore (see ../shared/bench/peers/README.md)
import numpy as np

RES = 64
PATH_DEPTH = 3
HALF_SIDE = 0.125
RADIANCE = 7.5 / (HALF_SIDE * HALF_SIDE)
COLUMNS = ["renderer", "version", "variant", "scene", "spp", "seconds", "rmse", "relmse",
           "peer", "load1"]


def read_ref(path):
    with OpenEXR.File(path) as f:
        ch = f.channels()
        if "RGB" in ch:
            img = np.asarray(ch["RGB"].pixels, dtype=np.float64)
        else:
            img = np.stack([np.asarray(ch[c].pixels, dtype=np.float64) for c in "RGB"], axis=-1)
    return img


def metrics(image, ref):
    x = np.where(np.isfinite(image), image, 0.0)
    d = x - ref
    return float(np.sqrt(np.mean(d * d))), float(np.mean(d * d / (ref * ref + 0.01)))


def square(half, y, up):
    verts = [(-half, y, -half), (half, y, -half), (half, y, half), (-half, y, half)]
    faces = [(0, 2, 1), (0, 3, 2)] if up else [(0, 1, 2), (0, 2, 3)]
    return verts, faces


def render(pyluxcore, engine, spp, threads, seed, sampler):
    t0 = time.perf_counter()
    scene = pyluxcore.Scene()
    p = pyluxcore.Properties()
    for key, val in [
        ("scene.camera.type", "perspective"),
        ("scene.camera.lookat.orig", [1.2, 0.5, 0.0]),
        ("scene.camera.lookat.target", [1.2, -0.5, 0.0]),
        ("scene.camera.up", [0.0, 0.0, -1.0]),
        ("scene.camera.fieldofview", 90.0),
        # As ../shared/bench/peers/render_peer.py: LuxCore's film is one pixel off without it.
        ("scene.camera.screenwindow", [-1.0, 1.0, -1.0 - 2.0 / RES, 1.0 - 2.0 / RES]),
        ("scene.materials.floor.type", "matte"),
        ("scene.materials.floor.kd", [0.5, 0.5, 0.5]),
        ("scene.materials.mirror.type", "mirror"),
        ("scene.materials.mirror.kr", [1.0, 1.0, 1.0]),
        ("scene.materials.light.type", "matte"),
        ("scene.materials.light.kd", [0.0, 0.0, 0.0]),
        ("scene.materials.light.emission", [RADIANCE, RADIANCE, RADIANCE]),
        ("scene.materials.light.emission.gain", [1.0, 1.0, 1.0]),
        ("scene.materials.light.emission.power", 0.0),
        ("scene.materials.light.emission.efficency", 0.0),
        ("scene.materials.light.emission.normalizebycolor", False),
        ("scene.materials.light.emission.twosided", False),
    ]:
        p.Set(pyluxcore.Property(key, val))
    scene.Parse(p)
    for name, (verts, faces) in [("floor", square(3.0, 0.0, True)), ("mirror", square(3.0, 1.0, False)),
                                 ("light", square(HALF_SIDE, 0.1, True))]:
        scene.DefineMesh(f"mesh-{name}", verts, faces, None, None, None, None)
        o = pyluxcore.Properties()
        o.Set(pyluxcore.Property(f"scene.objects.{name}.shape", f"mesh-{name}"))
        o.Set(pyluxcore.Property(f"scene.objects.{name}.material", name))
        scene.Parse(o)
    cfg = pyluxcore.Properties()
    common = [
        ("renderengine.type", engine), ("sampler.type", sampler),
        ("sampler.sobol.adaptive.strength", 0.0), ("sampler.random.adaptive.strength", 0.0),
        ("film.width", RES), ("film.height", RES),
        ("film.filter.type", "BOX"), ("film.filter.width", 0.5),
        ("batch.haltspp", spp), ("batch.halttime", 0), ("batch.haltthreshold", -1.0),
        ("native.threads.count", threads), ("renderengine.seed", seed + 1),
        ("film.outputs.0.type", "RGB"), ("film.outputs.0.filename", "RGB.exr"),
        ("film.imagepipelines.0.0.type", "TONEMAP_LINEAR"), ("film.imagepipelines.0.0.scale", 1.0),
        ("screen.refresh.interval", 10),
    ]
    if engine == "BIDIRCPU":
        specific = [("path.maxdepth", 3), ("light.maxdepth", 2),
                    ("path.russianroulette.depth", 5), ("light.russianroulette.depth", 5),
                    ("path.russianroulette.cap", 0.5)]
    else:
        specific = [("path.pathdepth.total", PATH_DEPTH), ("path.pathdepth.diffuse", PATH_DEPTH),
                    ("path.pathdepth.glossy", PATH_DEPTH), ("path.pathdepth.specular", PATH_DEPTH),
                    ("path.russianroulette.depth", 5), ("path.russianroulette.cap", 0.5),
                    ("path.clamping.variance.maxvalue", 0.0),
                    ("path.hybridbackforward.enable", False)]
    for key, val in common + specific:
        cfg.Set(pyluxcore.Property(key, val))
    config = pyluxcore.RenderConfig(cfg, scene)
    session = pyluxcore.RenderSession(config)
    session.Start()
    while True:
        time.sleep(min(0.25, max(0.005, 0.02 * (time.perf_counter() - t0))))
        session.UpdateStats()
        if session.HasDone():
            break
    session.Stop()
    seconds = time.perf_counter() - t0
    buf = np.zeros((RES, RES, 3), dtype=np.float32)
    session.GetFilm().GetOutputFloat(pyluxcore.FilmOutputType.RGB, buf)
    return buf[::-1].astype(np.float64), seconds  # LuxCore's film rows are bottom-up


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref", required=True, help="the closed form (bench --caustic --caustic-reference)")
    ap.add_argument("--engines", default="BIDIRCPU,PATHCPU")
    ap.add_argument("--spp", default="4,16,64,256,1024")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sampler", default=None, help="default: RANDOM for BIDIRCPU, SOBOL for PATHCPU")
    ap.add_argument("--csv")
    ap.add_argument("--check", type=int, metavar="SPP")
    a = ap.parse_args()
    ref = read_ref(a.ref)
    import pyluxcore
    logs = []
    pyluxcore.Init(lambda msg: logs.append(msg))
    rows = []
    for engine in a.engines.split(","):
        sampler = a.sampler or ("RANDOM" if engine == "BIDIRCPU" else "SOBOL")
        if a.check:
            image, seconds = render(pyluxcore, engine, a.check, a.threads, a.seed, sampler)
            _, relmse = metrics(image, ref)
            print(f"{engine} {sampler} {a.check} spp in {seconds:.2f} s: mean over the closed form "
                  f"{image.mean() / ref.mean():.5f}, relative MSE {relmse:.3e}", flush=True)
            continue
        render(pyluxcore, engine, 1, a.threads, a.seed, sampler)  # warm-up, untimed
        for spp in [int(s) for s in a.spp.split(",")]:
            image, seconds = render(pyluxcore, engine, spp, a.threads, a.seed, sampler)
            rmse, relmse = metrics(image, ref)
            row = {"renderer": "luxcore", "version": pyluxcore.Version(), "variant": engine,
                   "scene": "mirror-caustic", "spp": spp, "seconds": f"{seconds:.4f}",
                   "rmse": f"{rmse:.6e}", "relmse": f"{relmse:.6e}",
                   "peer": f"luxcore:{engine}", "load1": f"{os.getloadavg()[0]:.2f}"}
            print(",".join(str(row[c]) for c in COLUMNS), flush=True)
            rows.append(row)
    if a.csv and rows:
        with open(a.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS)
            w.writeheader()
            w.writerows(rows)
    os._exit(0)  # pyluxcore's threads crash the interpreter's normal exit


if __name__ == "__main__":
    main()
