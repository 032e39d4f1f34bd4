"""``ipm``: the command line (``docs/design``, "Command line").

Bad input ends with one line on stderr and exit code 2; set ``IPM_DEBUG=1`` for tracebacks.
A baseline that ran but produced no mesh (COLMAP registering too few images) exits with 3.
Heavy modules are imported after the thread settings, which XLA reads at import time.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path


def _views(args):
    """The input views of ``reconstruct`` / ``baseline`` (``ipm.capture.open_views``)."""
    from ipm.capture import open_views

    return open_views(args.views, args.up, args.colmap, args.images, args.masks, getattr(args, "image", None),
                      getattr(args, "mask", None), getattr(args, "fov", None), getattr(args, "segment", None))


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ipm", description="3D reconstruction by inverse procedural modeling")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("synth", help="render a synthetic reference case")
    s.add_argument("--case", default=None, help="case name (datasets_synthetic/NAME.json)")
    s.add_argument("--mesh", default=None, help="instead of --case: a mesh file (glTF / GLB, OBJ, PLY, STL, OFF) "
                   "rendered as a case of --generator (dishes or buildings), standing on the ground")
    s.add_argument("--generator", default=None, help="with --mesh: the generator of the object's class")
    s.add_argument("--up", choices=("y", "z"), default="y", help="with --mesh: the file's up axis")
    s.add_argument("--height", type=float, default=None, help="with --mesh: the object's height in scene units "
                   "(default: the file's units)")
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--views", type=int, default=1, help="number of views (view 0 is the input view)")
    s.add_argument("--res", type=int, default=256, help="image width and height in pixels")
    s.add_argument("--spp", type=int, default=64, help="samples per pixel of the RGB renders")
    s.add_argument("--layout", default="hemi", help="views: hemi (input view + hemisphere), ring (for COLMAP), photo (hemi cameras, photograph-like JPEGs) or held (input view + the hemisphere turned: views no row is given)")

    r = sub.add_parser("reconstruct", help="fit a procedural generator to masks")
    r.add_argument("--generator", required=True, help="generator name (e.g. dishes)")
    r.add_argument("--views", default=None, help="transforms.json with masks")
    r.add_argument("--image", default=None, help="instead of --views: one photo whose camera is unknown "
                   "(pitch, roll and field of view are estimated with the object; diff path)")
    r.add_argument("--mask", default=None, help="with --image: its mask (255 = object; default: the photo's alpha, "
                   "else segmented from its colours against a plain background)")
    r.add_argument("--segment", default=None, choices=["colour", "learned"],
                   help="with --image and no mask or alpha: colour (default; a plain background) or learned (a "
                   "photograph with a ground, shadows and a backdrop: the learned segmenter refined by GrabCut)")
    r.add_argument("--fov", type=float, default=None, help="with --image: the horizontal field of view in degrees (default: from the "
                   "photo's Exif 35 mm focal length, else estimated)")
    r.add_argument("--fov-grid", type=float, nargs="*", default=None, metavar="DEG",
                   help="for a field of view not given: fit once per value with it held and keep the lowest loss "
                        "(no values: 25 to 70 degrees in six steps); about as many times the time")
    r.add_argument("--out", required=True, help="output directory")
    r.add_argument("--method", default="diff", help="search path: diff (memetic + Adam), ga (tree-structured GA) "
                                                    "or learned (the regressor's proposal alone, no search)")
    r.add_argument("--n-input-views", type=int, default=None,
                   help="use only the first N frames of transforms.json (default: all)")
    r.add_argument("--prepared", default=None,
                   help="the method's preparation file from ipm prepare (ga: gene statistics, default: made in "
                        "the run; learned, and diff's learned start: the regressor; learned_photo, and the learned start of a photo "
                        "(camera unknown): its camera-hidden variant; default: the shipped ones)")
    r.add_argument("--start", default=None, choices=["presets", "learned"],
                   help="diff: the search's first population (learned, the default: the regressor's proposals "
                        "first where the camera is known; presets: the generator's presets)")
    r.add_argument("--max-tilt", type=float, default=None,
                   help="diff: let the object lean up to this many radians (default 0: upright, on y = 0)")
    r.add_argument("--window-weight", type=float, default=None,
                   help="diff: weight of the window-mask term for buildings with semantic images (default 1; 0: none)")
    r.add_argument("--renderer", default=None, choices=["auto", "jax", "mitsuba"],
                   help="diff: silhouette renderer (jax: edge sampling, one compiled function; mitsuba; "
                        "auto: jax, but mitsuba for an unknown field of view; "
                        "default: the profile's)")

    pr = sub.add_parser("prepare", help="a method's per-generator preparation stage (ga: gene statistics; learned: "
                        "the regressor; learned_photo: its camera-hidden variant; occnet: the occupancy network, all trained "
                        "on the generator's samples)")
    pr.add_argument("method", help="registered method name with a preparation stage (ga, learned, learned_photo, "
                                   "occnet)")
    pr.add_argument("--generator", required=True, help="generator name (e.g. trees)")
    pr.add_argument("--out", required=True, help="output file (JSON)")

    b = sub.add_parser("baseline", help="run a baseline (diffsdf, ngp, visual_hull, colmap_known, colmap_sfm, occnet)")
    b.add_argument("name", help="registered baseline name")
    b.add_argument("--views", default=None, help="transforms.json (masks; textured RGB for COLMAP)")
    b.add_argument("--out", required=True, help="output directory (mesh.ply, timing.json, info.json)")
    b.add_argument("--n-input-views", type=int, default=None,
                   help="use only the first N frames of transforms.json (default: all)")
    b.add_argument("--generator", default=None,
                   help="occnet: the class whose generator's samples it learns from (e.g. dishes, buildings)")
    b.add_argument("--prepared", default=None,
                   help="occnet: its weights from ipm prepare occnet (default: trained in the run)")

    e = sub.add_parser("evaluate", help="64-view silhouette IoU and the other metrics")
    e.add_argument("--reference", required=True, help="reference mesh (PLY)")
    e.add_argument("--mesh", required=True, help="reconstructed mesh (PLY)")
    e.add_argument("--out", required=True, help="metrics JSON")
    e.add_argument("--views", type=int, default=64, help="number of metric views")
    e.add_argument("--res", type=int, default=256, help="metric image size")
    e.add_argument("--grid", type=int, default=128, help="volumetric IoU grid size")
    e.add_argument("--preview", default=None, help="optional PNG strip of mask overlays")

    c = sub.add_parser("cases", help="list the synthetic cases with their split, class and family")
    c.add_argument("--split", default=None, choices=["dev", "test"], help="only this split")

    lr = sub.add_parser("reference-line", help="a table reference line from the reference mesh")
    lr.add_argument("name", help="convex_hull, bounding_sphere or reseeded_truth")
    lr.add_argument("--reference", required=True, help="reference mesh (PLY)")
    lr.add_argument("--truth", default=None, help="the case's ground_truth.json (reseeded_truth needs it)")
    lr.add_argument("--out", required=True, help="output directory (mesh.ply, timing.json)")

    g = sub.add_parser("generate", help="a generator's mesh from parameters (a reconstruction's params.json)")
    g.add_argument("--generator", required=True, help="generator name (dishes, trees, buildings)")
    g.add_argument("--params", required=True, help="params.json of a reconstruction, or {name: value}")
    g.add_argument("--lod", type=int, default=1, help="level of detail")
    g.add_argument("--out", required=True, help="output mesh (.glb: parts, materials, normals, parameters; .ply; "
                   ".json: a building's CityJSON 2.0 city model, LoD 2.2)")
    g.add_argument("--format", default=None, choices=("glb", "ply", "cityjson"), help="default: from --out's suffix")
    g.add_argument("--world", action="store_true", help="apply the reconstruction's pose (default: upright at the origin)")
    g.add_argument("--textures", default=None, help="a reconstruction's textures/ folder (PART.png on the generator's "
                   "UVs): the glb wears them at any level of detail and for edited parameters")

    for sp in (r, b):
        sp.add_argument("--up", default=None,
                        help="the input world's up axis (x, y, z, -x, -y, -z), or auto (perpendicular to the level cameras' "
                             "right vectors); the ground then at the masks' lowest common point; default y for "
                             "--views (the convention), auto for --colmap")
        sp.add_argument("--colmap", default=None, help="a COLMAP sparse model folder instead of --views (pinhole camera)")
        sp.add_argument("--images", default=None, help="with --colmap: the photos' folder")
        sp.add_argument("--masks", default=None, help="with --colmap: one mask per photo (NAME.png or STEM.png; default: "
                        "each photo's alpha, else segmented from its colours)")
    for sp in (r, pr, b):
        sp.add_argument("--profile", default="default", help="budget profile: smoke, default, paper")
        sp.add_argument("--seed", type=int, default=0, help="random seed")
    for sp in (s, r, pr, b, e, lr, c, g):
        sp.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="CPU threads")
        sp.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="Mitsuba/JAX device")
        sp.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _run(args) -> int:
    from ipm.errors import UserError
    from ipm.runtime import configure_threads

    if args.command == "reconstruct":
        from ipm.methods import METHODS

        quick = METHODS[args.method].compiles
    else:
        quick = False
    configure_threads(args.threads, args.device, quick_compile=quick)
    if args.command == "synth":
        from ipm.runtime import set_mitsuba_variant
        from ipm.synth import mesh_case, synthesize

        if (args.case is None) == (args.mesh is None):
            raise UserError("give one of --case and --mesh")
        if args.mesh is not None and args.generator is None:
            raise UserError("--mesh needs --generator (dishes or buildings)")
        if args.mesh is None and args.generator is not None:
            raise UserError("--generator applies to --mesh only (a case names its own)")
        case = args.case if args.mesh is None else mesh_case(args.mesh, args.generator, args.up, args.height)
        set_mitsuba_variant(args.device, args.threads)
        synthesize(case, args.out, n_views=args.views, res=args.res, spp=args.spp, progress=not args.quiet,
                   layout=args.layout)
    elif args.command == "reconstruct":
        from ipm.methods import METHODS, check_generator
        from ipm.runtime import set_mitsuba_variant

        method = METHODS[args.method]
        if not method.uses_generator:
            hint = f" --generator {args.generator}" if method.learns_generator else ""
            raise UserError(f"{args.method!r} is a baseline: use ipm baseline {args.method}{hint}")
        extra = {}
        if args.prepared is not None:
            if method.prepare is None and not (args.method == "diff" or method.withholds_camera):  # learned starts
                raise UserError(f"method {args.method!r} has no preparation stage (--prepared)")
            if not Path(args.prepared).is_file():
                raise UserError(f"--prepared: no such file {args.prepared}")
            extra["prepared"] = args.prepared
        for name in ("max_tilt", "window_weight"):  # checked with the profile's other settings
            value, flag = getattr(args, name), "--" + name.replace("_", "-")
            if value is None:
                continue
            if args.method != "diff":
                raise UserError(f"{flag} applies to the diff path only")
            extra[name] = value
        for flag, value in (("--fov-grid", args.fov_grid), ("--renderer", args.renderer), ("--start", args.start)):
            if value is not None and args.method not in ("diff", "photo"):
                raise UserError(f"{flag} applies to the diff path only")
        if args.fov_grid is not None:
            from ipm.photo import FOV_GRID

            extra["fov_grid"] = tuple(args.fov_grid) or FOV_GRID  # checked by get_profile
        for name in ("renderer", "start"):
            if getattr(args, name) is not None:
                extra[name] = getattr(args, name)
        from ipm.generators import GENERATORS  # after the flags' checks, which need no generator (JAX) imported

        GENERATORS[args.generator]  # unknown names, before any rendering
        check_generator(args.method, args.generator)
        views = _views(args)
        set_mitsuba_variant(args.device, args.threads)
        info = method(views, args.out, generator=args.generator, profile=args.profile, seed=args.seed,
                      progress=not args.quiet, n_input_views=args.n_input_views, **extra)
        if "final_loss" in info:
            print(f"{args.out}: final loss {info['final_loss']:.5f} after {info['evaluations']} evaluations")
        else:
            print(f"{args.out}: written")
        if args.image is not None:  # the figure a user looks at first
            from ipm.render.preview import photo_sheet

            photo_sheet(args.image, os.path.join(args.out, "mesh.ply"), info["camera"],
                        os.path.join(args.out, "overview.png"))
            cam = info["camera"]
            chosen = " (chosen from the grid)" if cam.get("fov_from_grid") else \
                " (proposed by the learned regressor)" if cam.get("proposed") and not cam.get("fov_given") else ""
            print(f"{args.out}: camera pitch {cam['pitch_deg']:.1f} deg, roll {cam['roll_deg']:.1f} deg, "
                  f"field of view {cam['fov_x_deg']:.1f} deg{chosen}; figure in overview.png")
    elif args.command == "prepare":
        from ipm.methods import METHODS, check_generator

        method = METHODS[args.method]
        if method.prepare is None:
            raise UserError(f"method {args.method!r} has no preparation stage")
        from ipm.generators import GENERATORS

        GENERATORS[args.generator]
        check_generator(args.method, args.generator)
        info = method.prepare(args.generator, args.out, profile=args.profile, seed=args.seed,
                              progress=not args.quiet)
        print(f"{args.out}: {args.method} preparation for {args.generator} in {info['seconds']:.1f} s")
    elif args.command == "baseline":
        from ipm.generators import GENERATORS
        from ipm.methods import METHODS
        from ipm.runtime import set_mitsuba_variant

        method = METHODS[args.name]
        if method.uses_generator:
            raise UserError(f"{args.name!r} is not a baseline: use ipm reconstruct --method {args.name}")
        extra = {}
        if method.learns_generator:
            if args.generator is None:
                raise UserError(f"{args.name!r} learns from a generator's samples: give --generator (e.g. dishes)")
            GENERATORS[args.generator]  # fail fast on unknown names
            extra["generator"] = args.generator
        elif args.generator is not None:
            raise UserError(f"baseline {args.name!r} takes no --generator")
        if args.prepared is not None:
            if method.prepare is None:
                raise UserError(f"baseline {args.name!r} has no preparation stage (--prepared)")
            extra["prepared"] = args.prepared
        views = _views(args)
        set_mitsuba_variant(args.device, args.threads)
        info = method(views, args.out, profile=args.profile, seed=args.seed, progress=not args.quiet,
                      n_input_views=args.n_input_views, **extra)
        if info.get("failed"):
            print(f"{args.out}: no mesh: {info['failed']}")
            return 3
        print(f"{args.out}: mesh in {info['seconds']:.1f} s")
    elif args.command == "evaluate":
        from ipm.metrics.evaluate import evaluate_files

        m = evaluate_files(args.reference, args.mesh, args.out, n_views=args.views, res=args.res,
                           grid=args.grid, preview_path=args.preview)
        print(f"{args.out}: IoU {m['iou_mean']:.4f} (min {m['iou_min']:.4f}), volumetric IoU {m['viou']:.4f}")
    elif args.command == "cases":
        from ipm.cases import describe_cases

        print(describe_cases(args.split))
    elif args.command == "generate":
        from ipm.generate import generate

        info = generate(args.generator, args.params, args.lod, args.out, world=args.world, fmt=args.format,
                        textures=args.textures)
        parts = ", ".join(f"{k} {v}" for k, v in info["parts"].items())
        size = f"{info['triangles']} triangles" if "triangles" in info else f"{info['surfaces']} surfaces"
        print(f"{args.out}: {size} ({parts})")
    elif args.command == "reference-line":
        from ipm.reference_lines import write_reference_line

        write_reference_line(args.name, args.reference, args.out, truth=args.truth)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from ipm.errors import UserError

    try:
        return _run(args)
    except UserError as exc:
        print(f"ipm {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"ipm {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001  one line for the user; IPM_DEBUG=1 shows the traceback
        if os.environ.get("IPM_DEBUG"):
            raise
        print(f"ipm {args.command}: failed: {type(exc).__name__}: {exc} (IPM_DEBUG=1 for details)", file=sys.stderr)
        return 1


def run() -> None:
    """The ``ipm`` command: :func:`main`, then the process ends at once with its status
    (``ipm.runtime.exit_now``: no teardown of the libraries it loaded)."""
    from ipm.runtime import exit_now

    exit_now(main())


if __name__ == "__main__":
    run()
