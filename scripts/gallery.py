"""``make gallery``: the plot kinds of every example, from the examples as they ship (docs/gallery.md).

Each ``configs/examples/*.yaml`` names the ``rbx plot`` kinds it is made for in its first line (``# plots: orbit,
phase, birkhoff --wall bottom``) and records what they need. The gallery runs each example as it ships — its
trajectories, its recorded fields, its ``every`` — for fewer collisions (``--collisions``, 2000), draws each of its
kinds with the CLI's defaults (:func:`rbx.cli.plot.make_figure`) into ``docs/gallery/<scene>-<kind>.png``, and
writes ``docs/gallery.md``: one picture per kind and scene with a line of caption. A kind that an example lists but
cannot draw fails the script (exit 1), as it fails tests/test_gallery.py. It also draws the README's quick-start
picture, ``docs/quickstart.png``: the circle example in full, ``rbx plot --kind orbit``.

    python scripts/gallery.py [--out docs] [--collisions 2000] [--only strip,box] [--dpi 80]
"""
import argparse
import glob
import os
import sys
import tempfile
import traceback

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import rbx  # noqa: E402
from rbx.cli.common import UserError  # noqa: E402
from rbx.cli.plot import make_figure  # noqa: E402
from rbx.plotting import save  # noqa: E402

#: what each kind shows, for the caption
SHOWS = {
    "orbit": "path of the centre in the table (solid: the table; dashed: the shrunk table the centre sees)",
    "orbit3d": "3D path of the centre beside its horizontal projection",
    "phase": "boundary map and tangential velocity against spin at each collision",
    "series": "x against the collision step over 1/100, 1/10 and all of the run",
    "diffusion": "ensemble mean-square displacement with the fitted 2Dt + c (D per collision and per unit time; "
                 "where free corridors make the horizon infinite, only b, half the MSD's slope over the window, said "
                 "in red), and the final displacements (against the Gaussian of the fitted MSD, not drawn where the "
                 "horizon is infinite)",
    "escape": "survival of the exit path length with the exponential rate fitted where it describes the data (and "
              "the trapped share, where survival levels off); where specular walls keep each disc's spin, every "
              "orbit leaves at its own rate: no single rate is fitted, the mean one at the start is drawn dashed",
    "birkhoff": "Birkhoff section (arc length, sin ψ) coloured by the spin share",
    "poincare": "Poincaré section by the plane z = 0.5 (upward crossings) coloured by the spin share",
}
#: examples of another command on a scene the gallery already has
SAME_SCENE = {"lyapunov-sinai.yaml"}


def example_kinds(config):
    """The plot kinds an example config is made for, from its first line ``# plots: orbit, birkhoff --wall W   (…)``
    -> list of (kind, {option: value}); empty if it names none."""
    with open(config) as f:
        first = f.readline()
    if not first.startswith("# plots:"):
        return []
    out = []
    for item in first[len("# plots:"):].split("(")[0].split(","):
        words = item.split()
        options = {}
        for flag, value in zip(words[1::2], words[2::2]):
            options[flag.lstrip("-").replace("-", "_")] = value
        out.append((words[0], options))
    return out


def shipped_run(config, folder, collisions):
    """A run of the example ``config`` as it ships, for at most ``collisions`` collisions -> path of its HDF5
    file."""
    exp = rbx.load(config)
    path = os.path.join(folder, os.path.basename(config).replace(".yaml", ".h5"))
    rbx.simulate(exp, collisions=min(collisions, exp.run.collisions), output=path, force=True)
    return path


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=os.path.join(ROOT, "docs"))
    p.add_argument("--collisions", type=int, default=2000)
    p.add_argument("--only", help="comma-separated scene names (config file stems)")
    p.add_argument("--dpi", type=int, default=80)
    args = p.parse_args(argv)
    configs = sorted(glob.glob(os.path.join(ROOT, "configs", "examples", "*.yaml")))
    configs = [c for c in configs if os.path.basename(c) not in SAME_SCENE]
    if args.only:
        keep = set(args.only.split(","))
        configs = [c for c in configs if os.path.basename(c)[:-5] in keep]
    pictures = os.path.join(args.out, "gallery")
    os.makedirs(pictures, exist_ok=True)
    lines = ["# Gallery", "",
             "The `rbx plot` kinds of every example (`configs/examples/`; each names its kinds in its first line, "
             "`# plots: …`), drawn with the defaults from the example as it ships — its trajectories, its recorded "
             f"fields — cut to {args.collisions} collisions at most. Made by `make gallery` (scripts/gallery.py).",
             ""]
    failed = 0
    with tempfile.TemporaryDirectory() as folder:
        for config in configs:
            scene = os.path.basename(config)[:-5]
            print(f"{scene}: simulating", flush=True)
            run = shipped_run(config, folder, args.collisions)
            lines += [f"## {scene}", "", f"`configs/examples/{scene}.yaml`", ""]
            for kind, options in example_kinds(config):
                flags = "".join(f" --{k.replace('_', '-')} {v}" for k, v in options.items())
                try:
                    fig = make_figure(run, kind, **options)
                except Exception as exc:     # an example that cannot draw a kind it lists: say so, draw the rest
                    if not isinstance(exc, UserError):
                        traceback.print_exc()
                    print(f"  FAILED {kind}{flags}: {exc}", flush=True)
                    failed += 1
                    continue
                name = f"{scene}-{kind}.png"
                save(fig, os.path.join(pictures, name), dpi=args.dpi)     # as rbx plot saves it
                print(f"  wrote {name}", flush=True)
                lines += [f"![{scene} {kind}](gallery/{name})", "",
                          f"*{scene}, `rbx plot --kind {kind}{flags}`*: {SHOWS[kind]}.", ""]
        if not args.only:
            # the README's quick start, exactly as it says: the circle example in full, its orbit
            print("quick start: circle", flush=True)
            run = os.path.join(folder, "quickstart.h5")
            rbx.simulate(os.path.join(ROOT, "configs", "examples", "circle.yaml"), output=run, force=True)
            save(make_figure(run, "orbit"), os.path.join(args.out, "quickstart.png"), dpi=100)
    if not args.only and not failed:
        stale = set(os.listdir(pictures)) - {line.split("(gallery/")[1][:-1] for line in lines
                                             if line.startswith("![")}
        for name in stale:              # pictures of kinds an example no longer lists
            os.remove(os.path.join(pictures, name))
        with open(os.path.join(args.out, "gallery.md"), "w") as f:
            f.write("\n".join(lines))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
