#!/usr/bin/env python3
"""Writes the material test scenes of this folder (Python 3 standard library only).

  python3 scenes/materials/make_scenes.py

All scenes share `materials.bin` (a checkered floor, a square area light, a UV sphere of radius
0.5 with normals and texture coordinates) and the same camera, light and sky colour:

  glass-smooth     a smooth glass sphere (ior 1.5, absorbing: attenuationColor [0.9, 0.75, 0.55]
                   at 1 m) on the floor
  glass-rough      the same with roughness 0.3 (GGX alpha 0.09)
  subsurface       a scattering sphere (KHR_materials_volume_scatter) behind a smooth ior-1.5
                   boundary: extinction 16-28 per metre (mean free path 3.6-6.2 % of the
                   diameter), multiscatterColor [0.85, 0.55, 0.3], Henyey-Greenstein g 0.3
  subsurface-matched  the same medium behind an index-matched (ior 1.0) boundary
  extensions       four small spheres: diffuse transmission, clear coat, sheen, anisotropy

Each scene has a `.settings.json` beside it. The floor and light are Lambertian
(KHR_materials_specular factor 0) and the light emits from its front (lower) face only.
"""
import base64
import json
import math
import struct
from pathlib import Path

HERE = Path(__file__).resolve().parent
BIN = "materials.bin"


class Buffer:
    def __init__(self):
        self.data = bytearray()
        self.views, self.accessors = [], []

    def add(self, fmt, rows, kind, target, minmax=False):
        while len(self.data) % 4:
            self.data.append(0)
        off = len(self.data)
        for r in rows:
            self.data += struct.pack("<" + fmt, *r)
        self.views.append({"buffer": 0, "byteOffset": off, "byteLength": len(self.data) - off,
                           "target": target})
        comp = {"f": 5126, "I": 5125}[fmt[0]]
        acc = {"bufferView": len(self.views) - 1, "componentType": comp, "count": len(rows),
               "type": kind}
        if minmax:
            acc["min"] = [min(r[i] for r in rows) for i in range(len(rows[0]))]
            acc["max"] = [max(r[i] for r in rows) for i in range(len(rows[0]))]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def mesh(self, positions, indices, normals=None, uvs=None):
        attrs = {"POSITION": self.add("fff", positions, "VEC3", 34962, minmax=True)}
        if normals:
            attrs["NORMAL"] = self.add("fff", normals, "VEC3", 34962)
        if uvs:
            attrs["TEXCOORD_0"] = self.add("ff", uvs, "VEC2", 34962)
        idx = self.add("I", [(i,) for tri in indices for i in tri], "SCALAR", 34963)
        return {"attributes": attrs, "indices": idx}


def quad_grid(x0, z0, size, n, parity):
    """Floor tiles (y = 0, facing +y) of an n x n checkerboard whose (i + j) % 2 == parity."""
    pos, idx = [], []
    for i in range(n):
        for j in range(n):
            if (i + j) % 2 != parity:
                continue
            a, b = x0 + i * size, z0 + j * size
            k = len(pos)
            pos += [(a, 0.0, b), (a, 0.0, b + size), (a + size, 0.0, b + size), (a + size, 0.0, b)]
            idx += [(k, k + 1, k + 2), (k, k + 2, k + 3)]
    return pos, idx


def uv_sphere(segments=48, rings=32):
    """A closed UV sphere of radius 0.5 at the origin, wound counter-clockwise seen from outside."""
    pos, nrm, uv, idx = [], [], [], []
    for r in range(rings + 1):
        th = math.pi * r / rings
        for s in range(segments + 1):
            ph = 2 * math.pi * s / segments
            n = (math.sin(th) * math.cos(ph), math.cos(th), -math.sin(th) * math.sin(ph))
            if r in (0, rings):
                n = (0.0, math.cos(th), 0.0)
            nrm.append(n)
            pos.append(tuple(0.5 * c for c in n))
            uv.append((s / segments, r / rings))
    # The seam column (s = segments) repeats s = 0 at the same positions: the mesh is closed by
    # position (the renderer's closed-volume check compares positions), and the poles are fans.
    row = segments + 1
    for r in range(rings):
        for s in range(segments):
            a, b = r * row + s, (r + 1) * row + s
            if r != 0:
                idx.append((a, b, a + 1))
            if r != rings - 1:
                idx.append((a + 1, b, b + 1))
    return pos, nrm, uv, idx


def look_at_quat(eye, target):
    f = [t - e for t, e in zip(target, eye)]
    n = math.sqrt(sum(c * c for c in f))
    f = [c / n for c in f]
    up = (0.0, 1.0, 0.0)
    r = (f[1] * up[2] - f[2] * up[1], f[2] * up[0] - f[0] * up[2], f[0] * up[1] - f[1] * up[0])
    n = math.sqrt(sum(c * c for c in r))
    r = [c / n for c in r]
    u = (r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0])
    b = [-c for c in f]
    m = [[r[0], u[0], b[0]], [r[1], u[1], b[1]], [r[2], u[2], b[2]]]  # columns: right, up, back
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = 0.5 / math.sqrt(tr + 1.0)
        return [(m[2][1] - m[1][2]) * s, (m[0][2] - m[2][0]) * s, (m[1][0] - m[0][1]) * s, 0.25 / s]
    raise ValueError("camera too far from the default orientation for this helper")


def lambert(name, rgb, double_sided=True):
    return {"name": name, "doubleSided": double_sided,
            "pbrMetallicRoughness": {"baseColorFactor": [*rgb, 1.0], "metallicFactor": 0.0,
                                     "roughnessFactor": 1.0},
            "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}}


LIGHT = {"name": "light", "doubleSided": False, "emissiveFactor": [1.0, 0.9, 0.75],
         "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0.0,
                                  "roughnessFactor": 1.0},
         "extensions": {"KHR_materials_specular": {"specularFactor": 0.0},
                        "KHR_materials_emissive_strength": {"emissiveStrength": 12.0}}}


def glass(roughness, ior=1.5):
    return {"name": f"glass-r{roughness}",
            "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0.0,
                                     "roughnessFactor": roughness},
            "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0},
                           "KHR_materials_ior": {"ior": ior},
                           "KHR_materials_volume": {"thicknessFactor": 1.0,
                                                    "attenuationColor": [0.9, 0.75, 0.55],
                                                    "attenuationDistance": 1.0}}}


def scattering(ior):
    return {"name": f"subsurface-ior{ior}",
            "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0.0,
                                     "roughnessFactor": 0.0},
            "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0},
                           "KHR_materials_ior": {"ior": ior},
                           "KHR_materials_volume": {"thicknessFactor": 1.0,
                                                    "attenuationColor": [0.45, 0.35, 0.25],
                                                    "attenuationDistance": 0.05},
                           "KHR_materials_volume_scatter": {"multiscatterColor": [0.85, 0.55, 0.3],
                                                            "scatterAnisotropy": 0.3}}}


EXTENSION_MATERIALS = [
    {"name": "diffuse-transmission",
     "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.85, 0.8, 1], "metallicFactor": 0.0,
                              "roughnessFactor": 0.6},
     "extensions": {"KHR_materials_diffuse_transmission": {
         "diffuseTransmissionFactor": 0.7, "diffuseTransmissionColorFactor": [1.0, 0.55, 0.2]}}},
    {"name": "clearcoat",
     "pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.05, 0.05, 1], "metallicFactor": 0.0,
                              "roughnessFactor": 0.7},
     "extensions": {"KHR_materials_clearcoat": {"clearcoatFactor": 1.0,
                                                "clearcoatRoughnessFactor": 0.03}}},
    {"name": "sheen",
     "pbrMetallicRoughness": {"baseColorFactor": [0.05, 0.08, 0.3, 1], "metallicFactor": 0.0,
                              "roughnessFactor": 0.9},
     "extensions": {"KHR_materials_sheen": {"sheenColorFactor": [1.0, 0.85, 0.7],
                                            "sheenRoughnessFactor": 0.35}}},
    {"name": "anisotropy",
     "pbrMetallicRoughness": {"baseColorFactor": [0.95, 0.75, 0.45, 1], "metallicFactor": 1.0,
                              "roughnessFactor": 0.25},
     "extensions": {"KHR_materials_anisotropy": {"anisotropyStrength": 0.9,
                                                 "anisotropyRotation": 0.0}}},
]


def main():
    buf = Buffer()
    light_pos = [(0.0, 2.2, 0.0), (1.2, 2.2, 0.0), (1.2, 2.2, 1.2), (0.0, 2.2, 1.2)]
    prims = {
        "floor-light": buf.mesh(*quad_grid(-2.0, -2.0, 0.5, 8, 0)),
        "floor-dark": buf.mesh(*quad_grid(-2.0, -2.0, 0.5, 8, 1)),
        # Facing -y (down): counter-clockwise seen from below.
        "light": buf.mesh(light_pos, [(0, 1, 2), (0, 2, 3)]),
    }
    sp, sn, su, si = uv_sphere()
    prims["sphere"] = buf.mesh(sp, si, normals=sn, uvs=su)
    (HERE / BIN).write_bytes(bytes(buf.data))
    ntris = len(si)

    def scene(name, what, objects, eye, target, yfov, width, height, spp):
        """objects: (material dict, translation, scale) spheres."""
        materials = [lambert("floor-light", (0.75, 0.72, 0.68)), lambert("floor-dark", (0.12, 0.14, 0.18)),
                     LIGHT]
        meshes = [{"name": "floor-light", "primitives": [{**prims["floor-light"], "material": 0}]},
                  {"name": "floor-dark", "primitives": [{**prims["floor-dark"], "material": 1}]},
                  {"name": "light", "primitives": [{**prims["light"], "material": 2}]}]
        nodes = [{"name": "floor-light", "mesh": 0}, {"name": "floor-dark", "mesh": 1},
                 {"name": "light", "mesh": 2, "translation": [-0.1, 0.0, -0.9]}]
        for k, (mat, t, s) in enumerate(objects):
            materials.append(mat)
            meshes.append({"name": f"sphere-{mat['name']}",
                           "primitives": [{**prims["sphere"], "material": len(materials) - 1}]})
            nodes.append({"name": mat["name"], "mesh": len(meshes) - 1, "translation": t,
                          "scale": [s, s, s]})
        nodes.append({"name": "camera", "camera": 0, "translation": list(eye),
                      "rotation": look_at_quat(eye, target)})
        used = sorted({"KHR_materials_specular", "KHR_materials_emissive_strength"}
                      | {e for m in materials for e in m.get("extensions", {})})
        g = {"asset": {"version": "2.0", "generator": f"renderfarm scenes/materials/make_scenes.py: {what}"},
             "extensionsUsed": used, "scene": 0,
             "scenes": [{"name": name, "nodes": list(range(len(nodes)))}],
             "nodes": nodes, "meshes": meshes, "materials": materials,
             "cameras": [{"name": "camera", "type": "perspective",
                          "perspective": {"yfov": yfov, "aspectRatio": width / height,
                                          "znear": 0.01, "zfar": 100.0}}],
             "accessors": buf.accessors, "bufferViews": buf.views,
             "buffers": [{"uri": BIN, "byteLength": len(buf.data)}]}
        (HERE / f"{name}.gltf").write_text(json.dumps(g, indent=1) + "\n")
        settings = {"width": width, "height": height, "spp": spp, "max_depth": 1024, "seed": 0,
                    "environment": {"color": [0.16, 0.2, 0.26]}}
        (HERE / f"{name}.settings.json").write_text(json.dumps(settings) + "\n")

    eye, target = (0.0, 1.3, 2.4), (0.0, 0.42, 0.0)
    centre = [0.0, 0.5, 0.0]
    scene("glass-smooth", f"a smooth absorbing glass sphere (UV sphere, {ntris} triangles) on a checkered floor",
          [(glass(0.0), centre, 1.0)], eye, target, 0.55, 160, 160, 256)
    scene("glass-rough", "the glass sphere with roughness 0.3",
          [(glass(0.3), centre, 1.0)], eye, target, 0.55, 160, 160, 256)
    scene("subsurface", "a scattering sphere (KHR_materials_volume_scatter) behind a smooth ior-1.5 boundary",
          [(scattering(1.5), centre, 1.0)], eye, target, 0.55, 160, 160, 256)
    scene("subsurface-matched", "the scattering sphere behind an index-matched (ior 1.0) boundary",
          [(scattering(1.0), centre, 1.0)], eye, target, 0.55, 160, 160, 256)
    row = [(m, [x, 0.3, 0.0], 0.6) for m, x in zip(EXTENSION_MATERIALS, (-1.05, -0.35, 0.35, 1.05))]
    scene("extensions", "diffuse transmission, clear coat, sheen and anisotropy on four spheres",
          row, (0.0, 1.0, 2.6), (0.0, 0.3, 0.0), 0.42, 320, 128, 256)


if __name__ == "__main__":
    main()
