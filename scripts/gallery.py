"""``make gallery``: every plot kind on every example scene, for looking at (docs/gallery.md).

Simulates a short run of each ``configs/examples/*.yaml`` (every field recorded, every collision, fewer
collisions), draws each ``rbx plot`` kind that applies to it with the CLI's defaults (:func:`rbx.cli.plot.make_figure`)
into ``docs/gallery/<scene>-<kind>.png``, and writes ``docs/gallery.md``: one picture per kind and scene with a
line of caption, and the kinds that do not apply with rbx's own one-line reason.

    python scripts/gallery.py [--out docs] [--collisions 2000] [--only strip,box] [--dpi 80]
"""
import argparse
import dataclasses
import glob
import os
import sys
import tempfile
import traceback

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import rbx  # noqa: E402
from rbx.cli.common import UserError  # noqa: E402
from rbx.cli.plot import KINDS, make_figure  # noqa: E402
from rbx.model import FIELDS  # noqa: E402
from rbx.plotting import save  # noqa: E402

#: what each kind shows, for the caption
SHOWS = {
    "orbit": "path of the centre in the table (solid: the table; dashed: the shrunk table the centre sees)",
    "orbit3d": "3D path of the centre beside its horizontal projection",
    "phase": "boundary map and tangential velocity against spin at each collision",
    "series": "x against the collision step over 1/100, 1/10 and all of the run",
    "diffusion": "ensemble mean-square displacement with the fitted 2Dt + c, and the final displacements",
    "escape": "survival function of the exit path length with the fitted exponential rate",
    "birkhoff": "Birkhoff section (arc length, sin ψ) coloured by the spin share",
    "poincare": "Poincaré section by the plane z = 0.5 (upward crossings) coloured by the spin share",
}
#: examples of another command on a scene the gallery already has
SAME_SCENE = {"lyapunov-sinai.yaml"}
#: at most this many trajectories per scene (sampled starts only: explicit starts keep their number); 16 left the
#: diffusion coefficient of the Lorentz gases with a confidence interval as wide as D itself
MAX_TRAJECTORIES = 64


def small_run(config, folder, collisions):
    """A short run of the example ``config`` with every field recorded -> path of its HDF5 file."""
    exp = rbx.load(config)
    sampled = isinstance(exp.initial[0], str)          # ('sample', wall), else explicit states
    overrides = {"collisions": min(collisions, exp.run.collisions)}
    if sampled:
        overrides["trajectories"] = min(MAX_TRAJECTORIES, max(exp.run.trajectories, 8))
    exp = rbx.load(config, overrides)
    record = exp.output.record
    if exp.output.every == 1 or "position" not in record:
        record = tuple(f.name for f in FIELDS) if "position" in record or not record else record
    exp = exp.replace(output=dataclasses.replace(exp.output, record=record,
                                                 every=1 if "position" in record else exp.output.every))
    path = os.path.join(folder, os.path.basename(config).replace(".yaml", ".h5"))
    rbx.simulate(exp, output=path, force=True)
    return path


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=os.path.join(ROOT, "docs"))
    p.add_argument("--collisions", type=int, default=2000)
    p.add_argument("--only", help="comma-separated scene names (config file stems)")
    p.add_argument("--kinds", help="comma-separated plot kinds")
    p.add_argument("--dpi", type=int, default=80)
    args = p.parse_args(argv)
    configs = sorted(glob.glob(os.path.join(ROOT, "configs", "examples", "*.yaml")))
    configs = [c for c in configs if os.path.basename(c) not in SAME_SCENE]
    if args.only:
        keep = set(args.only.split(","))
        configs = [c for c in configs if os.path.basename(c)[:-5] in keep]
    kinds = args.kinds.split(",") if args.kinds else KINDS
    pictures = os.path.join(args.out, "gallery")
    os.makedirs(pictures, exist_ok=True)
    lines = ["# Gallery", "",
             "Every `rbx plot` kind on every example scene (`configs/examples/`), drawn with the defaults from a "
             f"short run ({args.collisions} collisions at most, every field recorded). Made by `make gallery` "
             "(scripts/gallery.py); a kind that does not apply to a scene is listed with rbx's own reason.", ""]
    failed = 0
    with tempfile.TemporaryDirectory() as folder:
        for config in configs:
            scene = os.path.basename(config)[:-5]
            print(f"{scene}: simulating", flush=True)
            run = small_run(config, folder, args.collisions)
            lines += [f"## {scene}", "", f"`configs/examples/{scene}.yaml`", ""]
            skipped = []
            for kind in kinds:
                try:
                    fig = make_figure(run, kind)
                except UserError as exc:
                    skipped.append(f"`{kind}`: {exc.problem}")
                    continue
                except Exception:     # a bug: say so and go on, so that one bad picture does not hide the rest
                    traceback.print_exc()
                    failed += 1
                    continue
                name = f"{scene}-{kind}.png"
                save(fig, os.path.join(pictures, name), dpi=args.dpi)     # as rbx plot saves it
                print(f"  wrote {name}", flush=True)
                lines += [f"![{scene} {kind}](gallery/{name})", "",
                          f"*{scene}, `rbx plot --kind {kind}`*: {SHOWS[kind]}.", ""]
            if skipped:
                lines += ["Not drawn: " + "; ".join(skipped) + ".", ""]
    if not args.only and not args.kinds:
        with open(os.path.join(args.out, "gallery.md"), "w") as f:
            f.write("\n".join(lines))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
