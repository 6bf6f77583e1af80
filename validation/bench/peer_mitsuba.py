"""Mitsuba 3 side of ``lightsim bench peer``: one ``ptracer`` render in its own process.

Run as ``python -m lightsim.validation.bench.peer_mitsuba SPEC.json``; the parent times
the whole process (interpreter start-up, Mitsuba import, LLVM JIT, render, writing). The
module imports only numpy and mitsuba, so the time is Mitsuba's, not ours.

The sensor is a ``perspective`` camera facing the wall with the film plane parallel to
it: image-plane pixels then map linearly onto equal squares of the wall, and a box
reconstruction filter makes every pixel the mean radiance L over its square. The wall
is Lambertian with albedo 1, so its irradiance is E = π L (W/m², i.e. lx when the light
is given in lm/sr). The light is a ``point`` emitter of intensity Φ/(4π).

Spec fields (JSON)
------------------
===============  =====  ========================================================
field            unit   meaning
===============  =====  ========================================================
``meshes``       —      list of {``ply``: path, ``bsdf``: Mitsuba BSDF dict,
                        ``face_normals``: bool}
``light``        m, cd  {``position``: [x, y, z], ``intensity``: Φ/(4π)}
``camera``       m, °   {``origin``, ``target``, ``up``, ``fov`` (along x)}
``resolution``   px     [W, H]
``spp``          —      light paths per pixel (W·H·spp paths in all)
``max_depth``    —      longest path (segments, camera connection included)
``seed``         —      sampler seed
``out``          —      .npy written: E (H, W) float64, row 0 = top of the image
===============  =====  ========================================================
"""

from __future__ import annotations

import json
import math
import sys

import numpy as np


def render(spec: dict) -> np.ndarray:
    """E (H, W) in lx of one ptracer render described by ``spec`` (see module doc)."""
    import mitsuba as mi

    mi.set_variant(spec.get("variant", "llvm_ad_rgb"))
    W, H = spec["resolution"]
    cam = spec["camera"]
    scene: dict = {
        "type": "scene",
        "integrator": {"type": "ptracer", "max_depth": int(spec["max_depth"]),
                       "hide_emitters": True},
        "sensor": {
            "type": "perspective", "fov": float(cam["fov"]), "fov_axis": "x",
            "near_clip": float(cam.get("near_clip", 1e-3)),
            "to_world": mi.ScalarTransform4f().look_at(origin=cam["origin"],
                                                       target=cam["target"], up=cam["up"]),
            "sampler": {"type": "independent", "sample_count": int(spec["spp"]),
                        "seed": int(spec.get("seed", 0))},
            "film": {"type": "hdrfilm", "width": int(W), "height": int(H),
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        },
        "light": {"type": "point", "position": spec["light"]["position"],
                  "intensity": {"type": "rgb", "value": [spec["light"]["intensity"]] * 3}},
    }
    for i, m in enumerate(spec["meshes"]):
        scene[f"mesh{i}"] = {"type": "ply", "filename": m["ply"],
                             "face_normals": bool(m.get("face_normals", False)),
                             "bsdf": m["bsdf"]}
    img = mi.render(mi.load_dict(scene), spp=int(spec["spp"]))
    L = np.asarray(img, dtype=np.float64)[..., :3].mean(axis=-1)
    return math.pi * L


def main(argv: list[str]) -> int:
    with open(argv[1]) as fh:
        spec = json.load(fh)
    np.save(spec["out"], render(spec))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
