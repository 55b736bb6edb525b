"""``make studies``: three parameter studies (configs/studies/*.yaml) run with rbx.sweep into data/studies/*.nc, drawn
into figures/studies/*.png, and docs/studies.md written with their numbers and run times.

1. λ₁ against κ, completely rough Sinai table and stadium, with the regular share (the specular value dashed);
2. the diffusion coefficient against κ, triangular Lorentz gas of finite horizon, random (½ rough) and completely
   rough rules (the specular gas dashed);
3. the share of billiard-measure starts that never reach the left wall within the run, and the mean return path to
   it against Kac's 4A/ℓ, rough rectangle and rough Sinai table.
"""
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import rbx  # noqa: E402
from rbx.cli.common import duration  # noqa: E402
from rbx.plotting import save, sweep_figure  # noqa: E402

CONFIGS = os.path.join(ROOT, "configs", "studies")
DATA = os.path.join(ROOT, "data", "studies")
FIGURES = os.path.join(ROOT, "figures", "studies")
KEY = "ball.inertia"
XLABEL = "κ = ball.inertia (2λ/R²) [–]"


def run(name):
    began = time.perf_counter()
    ds = rbx.sweep(os.path.join(CONFIGS, f"{name}.yaml"), os.path.join(DATA, f"{name}.nc"), force=True)
    seconds = time.perf_counter() - began
    print(f"{name}: {ds['done'].size} points in {duration(seconds)}", flush=True)
    return ds, seconds


def series(ds, var, label, colour=None, wilson=False):
    x = ds[KEY].values
    y = ds[var].values
    if wilson:
        err = np.vstack([y - ds[f"{var}_low"].values, ds[f"{var}_high"].values - y])
    else:
        err = ds[f"{var}_stderr"].values
    out = {"x": x, "y": y, "err": err, "label": label}
    if colour:
        out["color"] = colour
    return out


def ensemble(ds):
    return f"{ds.attrs['ensemble_trajectories']} trajectories × {ds.attrs['ensemble_collisions']} collisions per point"


def table(rows, header):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def pm(v, e, digits=3):
    return f"{v:.{digits}f} ± {e:.{digits}f}"


def study1(doc):
    sinai, t1 = run("lyapunov-sinai")
    stadium, t2 = run("lyapunov-stadium")
    sinai0, t3 = run("lyapunov-sinai-specular")
    stadium0, t4 = run("lyapunov-stadium-specular")
    total = t1 + t2 + t3 + t4
    refs = [{"x": None, "y": float(sinai0["lyapunov"][0]), "label": f"specular Sinai: {float(sinai0['lyapunov'][0]):.3f}",
             "color": "C0"},
            {"x": None, "y": float(stadium0["lyapunov"][0]), "ls": ":",
             "label": f"specular stadium: {float(stadium0['lyapunov'][0]):.3f}", "color": "C1"}]
    thr = 0.02
    # the specular Sinai per collision, from billiard-measure starts (spin kept) and from point-particle starts
    # (the classic billiard): measured here, with the command the text quotes
    example = os.path.join(ROOT, "configs", "examples", "lyapunov-sinai.yaml")
    classic = {}
    for label, change in (("spin", {}), ("point", {"initial": {"sample": "point_particle"}})):
        exp = rbx.load(example, {"boundary.default.rank": 0, **change})
        classic[label] = rbx.lyapunov(exp, collisions=5000, trajectories=8, exponents=1)
    per_collision = {k: pm(float(r.per_collision()[0]), float(r.per_collision(r.stderr)[0]))
                     for k, r in classic.items()}
    point_time = pm(float(classic["point"].exponents[0]), float(classic["point"].stderr[0]))
    panels = [
        {"series": [series(sinai, "lyapunov", "rough Sinai 2 × 1.5, scatterer 0.4", "C0"),
                    series(stadium, "lyapunov", "rough stadium, radius 0.5, length 1", "C1")],
         "references": refs, "xlabel": XLABEL, "ylabel": "λ₁ per unit time [1/T]",
         "title": "largest Lyapunov exponent (± standard error)"},
        {"series": [series(sinai, "regular_share", "rough Sinai", "C0", wilson=True),
                    series(stadium, "regular_share", "rough stadium", "C1", wilson=True)],
         "xlabel": XLABEL, "ylabel": f"share of orbits with λ₁ < {thr} [–]", "ylim": (-0.03, 1.03),
         "title": "regular orbits (Wilson, z = 1)"}]
    fig = sweep_figure(panels, f"Rough billiards against κ: disc R = 0.1, completely rough walls · {ensemble(sinai)} · "
                               f"run time {duration(total)}")
    save(fig, os.path.join(FIGURES, "lyapunov-kappa.png"))
    rows = []
    for i, k in enumerate(sinai[KEY].values):
        rows.append([f"{k:g}", pm(float(sinai["lyapunov"][i]), float(sinai["lyapunov_stderr"][i])),
                     f"{float(sinai['regular_share'][i]):.2f}",
                     pm(float(stadium["lyapunov"][i]), float(stadium["lyapunov_stderr"][i])),
                     f"{float(stadium['regular_share'][i]):.2f}"])
    doc.append(f"""## 1. λ₁ against κ: rough Sinai table and rough stadium

![λ₁ against κ](../figures/studies/lyapunov-kappa.png)

`configs/studies/lyapunov-sinai.yaml`, `lyapunov-stadium.yaml` (and their `-specular` references): {ensemble(sinai)},
trajectories from the billiard measure, λ₁ per unit time by `rbx.lyapunov` (warm-up a tenth, 10 segments; the error
is the spread of the trajectories when it exceeds the segments'); an orbit is counted regular when its own λ₁ < {thr}
per unit time (a threshold in the table's units: a table 100 times larger has exponents 100 times smaller; give
`{{regular_share: {{threshold: …}}}}` or `rbx lyapunov --threshold` for another scale). Specular (the `-specular`
files, with the same billiard-measure starts): Sinai {pm(float(sinai0['lyapunov'][0]),
float(sinai0['lyapunov_stderr'][0]))}, stadium {pm(float(stadium0['lyapunov'][0]),
float(stadium0['lyapunov_stderr'][0]))}.
These are not the classic billiards' λ₁ per unit time: a start from the billiard measure carries spin, which a
specular wall never changes, so each orbit's centre keeps a speed below 1 (the error bar is mostly the spread of
those speeds). Per collision they agree: the specular Sinai's {per_collision["spin"]} per collision against
{per_collision["point"]} from point-particle starts, whose λ₁ = {point_time} per unit time is the classic value
(`rbx lyapunov configs/examples/lyapunov-sinai.yaml --set boundary.default.rank=0 --trajectories 8 --collisions
5000 --exponents 1`, with `--set initial={{sample: point_particle}}` for the latter). Run time {duration(total)}.

{table(rows, ["κ", "Sinai λ₁ [1/T]", "Sinai regular share", "stadium λ₁ [1/T]", "stadium regular share"])}
""")
    return total


def study2(doc):
    rand, t1 = run("diffusion-lorentz-random")
    rough, t2 = run("diffusion-lorentz-rough")
    spec, t3 = run("diffusion-lorentz-specular")
    total = t1 + t2 + t3
    D0, e0 = float(spec["diffusion"][0]), float(spec["diffusion_stderr"][0])
    panels = [{"series": [series(rand, "diffusion", "random rule: rough with probability ½", "C0"),
                          series(rough, "diffusion", "completely rough", "C1")],
               "references": [{"x": None, "y": D0, "label": f"specular gas: D = {D0:.4f} ± {e0:.4f}"}],
               "xlabel": XLABEL, "ylabel": "D per unit time [L²/T]",
               "title": "diffusion coefficient (± standard error)"}]
    fig = sweep_figure(panels, "Triangular Lorentz gas of finite horizon (cell 1 × √3, scatterers 0.36, disc R = 0.1) "
                               f"· {ensemble(rand)} · run time {duration(total)}", width=8.5)
    save(fig, os.path.join(FIGURES, "diffusion-kappa.png"))
    rows = [[f"{k:g}", pm(float(rand["diffusion"][i]), float(rand["diffusion_stderr"][i]), 4),
             pm(float(rough["diffusion"][i]), float(rough["diffusion_stderr"][i]), 4)]
            for i, k in enumerate(rand[KEY].values)]
    doc.append(f"""## 2. Diffusion against κ: triangular Lorentz gas of finite horizon

![D against κ](../figures/studies/diffusion-kappa.png)

`configs/studies/diffusion-lorentz-random.yaml`, `-rough.yaml`, `-specular.yaml`: {ensemble(rand)}, from the
billiard measure; D = Σ|Δx|²/(4 Σ Δt) over 20 segments of each trajectory (positions unfolded), its error from the
spread of the segments or of the trajectories, whichever is larger. Specular gas: D = {pm(D0, e0, 4)} per unit
time. Run time {duration(total)}.

{table(rows, ["κ", "random rule D [L²/T]", "completely rough D [L²/T]"])}
""")
    return total


def study3(doc):
    out = {}
    total = 0.0
    for t in ("rectangle", "sinai"):
        out[t, "trapped"], s1 = run(f"trapped-{t}")
        out[t, "return"], s2 = run(f"return-{t}")
        total += s1 + s2
    names = {"rectangle": "rough rectangle 2 × 1", "sinai": "rough Sinai 2 × 1.5, scatterer 0.4"}
    colours = {"rectangle": "C0", "sinai": "C1"}
    trapped = [series(out[t, "trapped"], "trapped_share", names[t], colours[t], wilson=True) for t in names]
    ratios = []
    for t in names:
        ds = out[t, "return"]
        ratios.append({"x": ds[KEY].values, "y": ds["return_path_ratio"].values,
                       "err": ds["return_path_ratio_stderr"].values, "label": names[t], "color": colours[t]})
    one_minus = [{"x": out[t, "trapped"][KEY].values, "y": 1 - out[t, "trapped"]["trapped_share"].values,
                  "label": f"1 − never-reach share, {t}", "color": colours[t]} for t in names]
    panels = [{"series": trapped, "xlabel": XLABEL, "ylabel": "share never reaching the left wall [–]",
               "title": "starts on all walls (Wilson, z = 1)"},
              {"series": ratios, "references": [{"x": None, "y": 1.0, "label": "Kac: 4A/ℓ (ergodic)"}] + one_minus,
               "xlabel": XLABEL, "ylabel": "mean return path / (4A/ℓ) [–]",
               "title": "starts on the left wall (± s.e.)"}]
    r = out["rectangle", "return"]
    fig = sweep_figure(panels, f"Rough tables trap: left wall as the target · {ensemble(r)} · run time "
                               f"{duration(total)}")
    save(fig, os.path.join(FIGURES, "trapping-kappa.png"))
    rows = []
    for i, k in enumerate(r[KEY].values):
        row = [f"{k:g}"]
        for t in names:
            tr, ret = out[t, "trapped"], out[t, "return"]
            row += [f"{float(tr['trapped_share'][i]):.3f}",
                    pm(float(ret["return_path"][i]), float(ret["return_path_stderr"][i]), 2),
                    pm(float(ret["return_path_ratio"][i]), float(ret["return_path_ratio_stderr"][i]), 3)]
        rows.append(row)
    kac = {t: float(out[t, "return"]["return_path_kac"][0]) for t in names}
    doc.append(f"""## 3. Trapping against κ: the share that never reaches a wall, and Kac's return path

![trapping against κ](../figures/studies/trapping-kappa.png)

`configs/studies/trapped-*.yaml` (starts from the billiard measure on all walls; the left wall has the rule exit) and
`return-*.yaml` (starts on the left wall): {ensemble(r)}. Kac's lemma with Santaló's formula gives the mean return
path 4A/ℓ (rectangle {kac['rectangle']:.3f}, Sinai {kac['sinai']:.3f}) when almost every state reaches the wall; a
share of phase space that never does lowers it by that share, so with long enough runs the ratio would follow
1 − (never-reach share) (dashed lines of the right panel). Measured here, the two agree for the rectangle only
roughly (the ratio lies 0.01–0.07 above the line) and not for the Sinai table (at κ = 0.5: ratio ≈ 0.95 against
1 − 0.20): "never within 20 000 collisions" counts slow as well as trapped states, and the mean return path
leaves out the starts that did not return. The reading of these curves is open. Run time {duration(total)}.

{table(rows, ["κ", "rectangle: never reach", "rectangle: return path [L]", "rectangle: / 4A/ℓ",
              "Sinai: never reach", "Sinai: return path [L]", "Sinai: / 4A/ℓ"])}
""")
    return total


def main():
    os.makedirs(DATA, exist_ok=True)
    os.makedirs(FIGURES, exist_ok=True)
    began = time.perf_counter()
    doc = []
    times = [study1(doc), study2(doc), study3(doc)]
    wall = time.perf_counter() - began
    head = f"""# Studies

Three parameter studies made with `rbx sweep` / `rbx.sweep` (docs/reference.md §12): each is a set of study files in
`configs/studies/`, run by `make studies` (`scripts/studies.py`) into `data/studies/*.nc` and drawn into
`figures/studies/`. Every number has its error bar; every point's seed derives from the study's seed and the
point's values. `make studies` took {duration(wall)} here (2 cores; the studies {', '.join(duration(t) for t in times)},
the rest compiling and drawing).

A study file, and what it gives back:

```yaml
base: ../examples/lyapunov-sinai.yaml     # an experiment config (relative to the study file), or an inline mapping
set: {{initial: {{sample: billiard}}}}        # optional: dotted overrides made at every point
vary:                                     # dotted config keys: the product of all (zip: true varies them together)
  ball.inertia: [0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.7, 1.0]
  # table.radius: {{from: 0.1, to: 0.4, num: 4, scale: linear}}     # or scale: log
measure: [lyapunov, {{regular_share: {{threshold: 0.02}}}}]   # rbx/observables.py: the registry
ensemble: {{trajectories: 32, collisions: 80000, seed: 11}}
```

    rbx sweep STUDY.yaml -o RESULTS.nc [--scheduler ADDRESS] [--resume] [--force] [--quiet]
              [--set KEY=VALUE] [--trajectories M] [--collisions N]     # a shipped study, shortened
    rbx plot RESULTS.nc --kind sweep [--y OBSERVABLE] [--x KEY] [--logx] [--logy] [-o FIG.png]

A varied key names one number. An item of a list is named by its index in brackets, and `zip: true` (beside
`vary`) moves several together: the escape example's gate, `table.boundary[3].to[1]` and
`table.boundary[4].from[1]` zipped over the same values, sweeps the hole's size (its walls are specular: with
`set: {{initial: {{sample: point_particle}}}}` each point has one escape rate; a disc started with spin keeps it there,
each orbit leaves at its own rate, and `escape_rate` is NaN).

From Python the same: `rbx.sweep("STUDY.yaml", "RESULTS.nc", trajectories=4, collisions=5000,
sets={{"ball.radius": 0.05}})` is `rbx sweep STUDY.yaml -o RESULTS.nc --trajectories 4 --collisions 5000 --set
ball.radius=0.05` (the same checks, and the same numbers); it returns the results as an `xarray.Dataset`.

The results file opens with `xarray.open_dataset`: one dimension per varied key, `<observable>` and
`<observable>_stderr` (and companions such as `mean_free_path_santalo`, `return_path_kac`, `escape_rate_small_hole`,
`regular_share_low/high`),
per point `collisions`, `wall_time`, `seed`, `done`, the study's text, digest and provenance as attributes, and
`ensemble_orbits`: how many distinct orbits each point's ensemble holds (fewer than its trajectories where fixed
starts and no random numbers repeat each other; `rbx sweep` warns, and the study's figure says "copies"). Each
distinct orbit is run once: copies add no sample, and their errors are those of the distinct orbits.
Two observables say when their number is not what its name promises: `trapped_share_levelled` is 1 where survival
has levelled off by the end of the run (the share is then a trapped share) and 0 where it still falls (the share
counts the orbits not out yet and shrinks with longer runs); `return_path` and `return_angle_ks` are NaN where
some sample did not return within the run (the slow returns are missing: the mean of the others is biased low, and
a p-value would test the truncation, not the law), and the study's figure says so; raise `collisions`.
`lyapunov` and `regular_share` are NaN at a point where every orbit left the table (an exit) during its warm-up, or
too few segments were measured for an error; the study goes on to the other points, and `rbx sweep` warns once
per observable naming the first such point.

`--resume` continues `RESULTS.nc.partial` (or `RESULTS.nc`) only if it is this study's: the same digest, the
study's variables in their shapes, coordinates equal to the values the study defines, and points marked done that
hold a seed equal to the study's and a number where their observable always gives one (`energy_drift`,
`mean_free_path`, and `wall_time`); otherwise it refuses in one line naming the variable, exit 2.

Starts for comparisons with classic billiards: `set: {{initial: {{sample: point_particle}}}}` starts every trajectory
as a point particle's, the centre uniform in the area of the shrunk table and the direction uniform, |v| = 1 and no
spin (docs/reference.md §4). With a specular rule this is the classic billiard in its invariant measure: the mean
free path is then Santaló's πA/P of the shrunk table, the `mean_free_path` observable's companion
`mean_free_path_santalo` (checked in `tests/test_point_particle.py`, with the disc's mean first flight 8r/3π and
mean chord 16r/3π). Such starts meet an orbit of long chords more often, and in a table that is not ergodic (a
circle, a rectangle, a box) each orbit keeps its chords: under specular walls `mean_free_path` therefore weights
each point-particle orbit by its collisions per unit path, as if every orbit had run the same path, which is πA/P
in any table (circle of radius 0.9: 1.430 ± 0.030 against 1.414; pooled with equal weights it was the flow's mean
chord 16r/3π = 1.528; `tests/test_observables.py`); the weights cost variance (that error is twice the billiard
starts'). Under rough walls such orbits gain spin, these starts are no invariant measure, and πA/P is expected
only in an ergodic table. `{{sample: billiard}}` starts on the walls instead, with spin, so the centre is slower:
the specular Lorentz gas of study 2 diffuses at D = 0.069 ± 0.001 per unit time from a point particle's starts
(Machta–Zwanzig's random walk between traps: 0.063; `tests/test_observables.py`) and at 0.058 from the
billiard measure's.

Observables: {', '.join(sorted(rbx.observables.REGISTRY) if hasattr(rbx, 'observables') else [])}.

"""
    from rbx import observables
    head = head.replace("Observables: .", "Observables: " + ", ".join(
        f"`{o.name}` [{o.unit}]" for o in observables.REGISTRY.values()) + ".")
    with open(os.path.join(ROOT, "docs", "studies.md"), "w", encoding="utf-8") as fh:
        fh.write(head + "\n".join(doc))
    print(f"make studies: {duration(wall)}")


if __name__ == "__main__":
    main()
