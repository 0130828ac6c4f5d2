"""``jaxsss export SCENE.toml --to mitsuba|pbrt-v4 --out DIR``: the scene and its material for a production or
reference renderer (:mod:`jaxsss.export`).

Writes ``DIR/scene.xml`` (Mitsuba 3) or ``DIR/scene.pbrt`` (pbrt-v4) and the PLY meshes they reference. Keys the
target cannot represent (blockers, layer textures, a material texture, an environment map, a non-black background)
are refused with one line naming the key (exit 2).
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from jaxsss.cli._common import UNITS_EPILOG, CLIError, fmt, format_table, print_json

NAME = "export"
HELP = "export a scene file (TOML) to Mitsuba 3 (XML + PLY) or pbrt-v4 (.pbrt + PLY)"

DESCRIPTION = """\
Export a jaxsss scene (mesh, material, lights, camera, occluders) for rendering elsewhere. Lengths stay in mm and
coefficients in 1/mm; images of the exported scene hold radiance in W/(mm^2 sr), as jaxsss's.

mitsuba: a homogeneous medium inside the mesh (sigma_s = sigma_s' / (1 - g), Henyey-Greenstein phase), a null
boundary at eta = 1 else a dielectric, the volpathmis integrator, the same camera pixel for pixel (box filter).
Render with `mitsuba -m llvm_ad_rgb DIR/scene.xml` (or scalar_rgb). At eta != 1 a path tracer cannot connect a
smooth boundary to point, spot or directional lights: a warning says so.

pbrt-v4: the subsurface material (pbrt's photon beam diffusion BSSRDF) with sigma_a and sigma_s in 1/mm and
scale 1 (the scene is in mm), the volpath integrator. Render with `pbrt DIR/scene.pbrt`."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    from jaxsss.export import TARGETS

    p = subparsers.add_parser(NAME, help=HELP, description=DESCRIPTION, epilog=UNITS_EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", type=Path, help="scene file (TOML)")
    p.add_argument("--to", choices=TARGETS, required=True, help="target renderer")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory (created if missing)")
    p.add_argument("--spp", type=int, default=1024, metavar="N", help="samples per pixel written into the scene, "
                   ">= 1 (default 1024)")
    p.add_argument("--name", default="scene", help="file stem of the scene file (default: scene)")
    p.add_argument("--burley", action="store_true",
                   help="also fit Christensen-Burley normalized diffusion (Cycles, RenderMan) to the medium's "
                   "transport profile and print its parameters per channel (albedo A, shape d in mm, searchlight "
                   "mean free path in mm) and its error against transport (jaxsss.export.burley; needs a white "
                   "Monte Carlo table for the medium's g and eta)")
    p.add_argument("--json", action="store_true", help="print one JSON object (files written, warnings)")
    p.set_defaults(run=run)
    return p


def run(args) -> int:
    from jaxsss.export import mitsuba, pbrt
    from jaxsss.export.ply import OBJECT_ID
    from jaxsss.render.scene import load_scene

    if args.spp < 1:
        raise CLIError(f"--spp={args.spp} is outside the allowed range [1, inf)")
    if not args.name or "/" in args.name:
        raise CLIError(f"--name={args.name!r} must be a plain file stem (no '/')")
    scene = load_scene(args.scene)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if args.to == "mitsuba":
            path = mitsuba.write_scene(scene, args.out, spp=args.spp, name=args.name)
        else:
            path = pbrt.write_scene(scene, args.out, spp=args.spp, name=args.name)
    burley = None
    if args.burley:
        from jaxsss.export.burley import burley_fit

        fit = burley_fit(scene.material.medium)
        burley = {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in fit._asdict().items()}
    files = [str(Path(args.out) / f"{OBJECT_ID}.ply")] + [str(Path(args.out) / f"occluder_{i}.ply")
                                                        for i in range(len(scene.occluders))]
    notes = [str(w.message) for w in caught]
    if args.json:
        print_json({"target": args.to, "scene": str(path), "meshes": files, "warnings": notes,
                    **({"burley": burley} if burley is not None else {})})
        return 0
    for note in notes:
        print(f"warning: {note}")
    print(f"wrote {path} ({args.to}) and {len(files)} PLY mesh(es) in {args.out}")
    if burley is not None:
        print("Christensen-Burley normalized diffusion fitted to transport (per channel R, G, B):")
        rows = [[name, *(fmt(v) for v in burley[key])] for name, key in
                (("albedo A", "A"), ("shape d [mm]", "d"), ("mean free path [mm]", "mfp"),
                 ("rel. L2 error of 2 pi r R(r)", "error_l2"), ("max rel. error, 0.1-5 l_d", "error_max"))]
        print(format_table(["parameter", "R", "G", "B"], rows))
    return 0
