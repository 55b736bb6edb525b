"""``rbx animate RUN.h5 -o orbit.gif``: the ball moving in its table. Reads the run, never simulates.

The ball is drawn at its radius R with a radius marking its orientation θ, in the table drawn as ``rbx plot
--kind orbit`` draws it, with the path flown so far behind it. Frames are evenly spaced in time; between two
recorded collisions the flight is free, so the centre is a + v·(t − tᵢ) and θ goes linearly from θᵢ to θᵢ₊₁
(θ is recorded continuous and ω is constant in flight): the frames are exact, not smoothed. GIF is written with
Pillow (no system package); MP4 with ffmpeg when it is installed.
"""
import os
import time

import click
import numpy as np

from ..paths import FileError, written_whole
from .common import (Command, UserError, cannot_write, check_figure_target, display_path, duration, interrupted_exit,
                     quiet_option, report_and_exit, summary, user_errors)

NEEDED = ("time", "position", "velocity", "orientation")


@click.command(cls=Command)
@click.argument("run_file", metavar="RUN.h5", type=click.Path())
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="Animation to write: .gif (Pillow) or .mp4 (needs ffmpeg). Overwritten.")
@click.option("--trajectory", default=0, show_default=True, type=int, help="The trajectory to show.")
@click.option("--records", metavar="A:B", help="Record range, as a Python slice (default: all, or the first 200 "
                                              "collisions of a longer run).")
@click.option("--fps", default=20, show_default=True, type=click.IntRange(1, 100), help="Frames per second.")
@click.option("--frames", default=200, show_default=True, type=click.IntRange(2, 20000),
              help="Number of frames, evenly spaced in time over the records.")
@click.option("--dpi", default=80, show_default=True, type=click.IntRange(20, 600), help="Resolution of a frame.")
@quiet_option
@click.option("--debug", is_flag=True, help="Show a traceback with user errors.")
def animate(run_file, out, trajectory, records, fps, frames, dpi, quiet, debug):
    """Animate the ball of a 2D run RUN.h5 (written by rbx simulate with time, position, velocity and orientation
    recorded at every collision) moving in its table."""
    began = time.perf_counter()
    try:
        path = write_animation(run_file, out, trajectory, records, fps, frames, dpi)
    except UserError as exc:
        report_and_exit(exc, debug)
    except KeyboardInterrupt:
        interrupted_exit()
    summary(quiet, f"wrote {display_path(path)}: {frames} frames at {fps} fps in "
                   f"{duration(time.perf_counter() - began)}")


#: colours of a GIF's palette (one palette for every frame)
PALETTE = 64
#: without --records, at most this many collisions are animated (a long run would flash past)
DEFAULT_COLLISIONS = 200


def write_animation(run_file, out, trajectory=0, records=None, fps=20, frames=200, dpi=80):
    """Write the animation -> its path. Problems with the file, the selection or the format raise UserError."""
    from ..reader import Run
    from .plot import check_records, parse_records
    ext = os.path.splitext(out)[1].lower()
    if ext not in (".gif", ".mp4"):
        raise UserError(out, "-o", f"write a .gif or an .mp4, not '{ext or 'no extension'}'")
    if ext == ".mp4":
        from matplotlib import animation
        if not animation.writers.is_available("ffmpeg"):
            raise UserError(out, "-o", "an .mp4 needs ffmpeg, which is not installed: write a .gif")
    check_figure_target(out)
    rec = parse_records(records)
    with user_errors():
        with Run.open(run_file) as run:
            if run.dimension != 2:
                raise UserError(run.path, None, "animate draws 2D tables; this run is 3D (use rbx plot --kind orbit3d)")
            if not 0 <= trajectory < run.trajectories:
                raise UserError(run.path, "--trajectory", f"trajectory {trajectory} does not exist (the run has "
                                                          f"{run.trajectories}: 0–{run.trajectories - 1})")
            run.require(NEEDED, "animate")
            if run.every != 1:
                raise UserError(run.path, None, f"animate needs every collision recorded (output.every: 1; this run "
                                                f"has {run.every}): the flights between records are not straight")
            if records is None:
                rec = slice(0, DEFAULT_COLLISIONS + 1)
            check_records(rec, len(run.step), run.path, run)
            data = {f: run.read(f, [trajectory], rec)[0] for f in NEEDED}
            steps = run.step[rec]
            geom, R, scene = run.geometry(), run.radius, run.scene()
    ok = np.isfinite(data["time"])
    data = {f: v[ok] for f, v in data.items()}
    if len(data["time"]) < 2:
        raise UserError(run_file, "--records", "animate needs at least 2 records of the trajectory")
    if ext == ".gif":
        _check_gif_memory(frames, dpi)
    t, pos, theta = ball_frames(data["time"], data["position"], data["velocity"], data["orientation"], frames)
    title = f"{scene}\ntrajectory {trajectory} · collisions {steps[0]}–{steps[0] + len(data['time']) - 1}"
    try:
        with written_whole(out) as tmp:         # its folder exists: check_figure_target
            _render(tmp, ext, geom, R, data["position"], data["time"], t, pos, theta, title, fps, dpi)
    except (OSError, FileError) as exc:
        cannot_write(out, exc, "the animation")
    except MemoryError:      # the estimate is of the frames alone: Pillow's GIF encoder may still find too little
        raise UserError(out, "--frames", f"{frames} frames at --dpi {dpi} do not fit in this process's memory: "
                                         "fewer frames or a lower --dpi") from None
    return out


#: the animation's size in inches (its title may grow it a little); a GIF keeps every frame until it is written:
#: one byte per pixel after the palette, and Pillow's encoder about as much again (measured: 24 MB per frame at
#: dpi 600, 3600 × 3240 pixels)
GIF_INCHES = (6.0, 5.4)
GIF_BYTES_PER_PIXEL = 2.2


def _check_gif_memory(frames, dpi):
    """Refuse, as a :class:`UserError` naming ``--frames``, a GIF whose frames would not fit in this process's memory
    (``--frames 400 --dpi 600``: a MemoryError traceback under ``ulimit -v``, or the machine's memory)."""
    from ..simulation import memory_problem
    pixels = round(GIF_INCHES[0] * dpi) * round(GIF_INCHES[1] * dpi)
    need = frames * pixels * GIF_BYTES_PER_PIXEL + 8 * pixels       # the frames, and the canvas drawing them
    if memory_problem(1, int(need)) is not None:
        raise UserError(None, "--frames", f"{frames} frames of {round(GIF_INCHES[0] * dpi)} × "
                                          f"{round(GIF_INCHES[1] * dpi)} pixels (--dpi {dpi}) need about "
                                          f"{need / 2**30:.3g} GiB of memory, more than this process may have: fewer "
                                          "frames or a lower --dpi")


def ball_frames(time, position, velocity, orientation, frames):
    """Centre and orientation at ``frames`` times evenly spaced over [time[0], time[-1]] -> (t, position, θ).

    Between records i and i+1 (consecutive collisions) the centre flies freely: a = aᵢ + vᵢ·(t − tᵢ); θ turns at
    the constant rate (θᵢ₊₁ − θᵢ)/(tᵢ₊₁ − tᵢ)."""
    time = np.asarray(time, float)
    t = np.linspace(time[0], time[-1], frames)
    i = np.clip(np.searchsorted(time, t, side="right") - 1, 0, len(time) - 2)
    dt = t - time[i]
    pos = position[i] + velocity[i] * dt[:, None]
    span = time[i + 1] - time[i]
    frac = np.divide(dt, span, out=np.zeros_like(dt), where=span > 0)
    theta = orientation[i] + (orientation[i + 1] - orientation[i]) * frac
    return t, pos, theta


def _render(out, ext, geom, R, path, path_time, t, pos, theta, title, fps, dpi):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.patches import Circle

    from .. import plotting
    with plotting.style():
        fig = plotting._figure(6.0, 5.4, title)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        lo, hi = path.min(axis=0) - R, path.max(axis=0) + R
        plotting.draw_table_2d(ax, geom, lo, hi)
        plotting._round_caps(ax)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("x [L]")
        ax.set_ylabel("y [L]")
        trail, = ax.plot([], [], color=plotting._colour(0), lw=0.7, alpha=0.6)
        ball = Circle(pos[0], R, facecolor="#f4c542", edgecolor="0.1", lw=1.0, zorder=4)
        ax.add_patch(ball)
        mark, = ax.plot([], [], color="0.1", lw=1.6, zorder=5, solid_capstyle="round")
        clock = ax.set_title("")
        ax.autoscale_view()
        if ext == ".mp4":
            from matplotlib.animation import FFMpegWriter
            writer = FFMpegWriter(fps=fps)
            with writer.saving(fig, out, dpi):
                for k in range(len(t)):
                    _frame(k, t, pos, theta, R, path, path_time, trail, ball, mark, clock)
                    writer.grab_frame()
            return
        from PIL import Image
        fig.set_dpi(dpi)
        images, palette = [], None
        for k in range(len(t)):
            _frame(k, t, pos, theta, R, path, path_time, trail, ball, mark, clock)
            fig.canvas.draw()
            frame = Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3])
            if palette is None:     # the last frame has every colour the animation draws (the whole trail)
                _frame(len(t) - 1, t, pos, theta, R, path, path_time, trail, ball, mark, clock)
                fig.canvas.draw()
                last = Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3])
                palette = last.quantize(colors=PALETTE, method=Image.Quantize.MEDIANCUT)
            # one palette for all frames and no dithering: consecutive frames then differ only where the ball
            # moved, and the GIF stores just that rectangle (a palette per frame, dithered, changed every pixel:
            # 200 frames of a circle made 7.3 MB)
            images.append(frame.quantize(palette=palette, dither=Image.Dither.NONE))
        images[0].save(out, save_all=True, append_images=images[1:], duration=max(10, round(1000 / fps)), loop=0,
                       format="GIF", optimize=True, disposal=1)


def _frame(k, t, pos, theta, R, path, path_time, trail, ball, mark, clock):
    done = np.searchsorted(path_time, t[k], side="right")
    trail.set_data(np.append(path[:done, 0], pos[k, 0]), np.append(path[:done, 1], pos[k, 1]))
    ball.center = pos[k]
    tip = pos[k] + R * np.array([np.cos(theta[k]), np.sin(theta[k])])
    mark.set_data([pos[k, 0], tip[0]], [pos[k, 1], tip[1]])
    clock.set_text(f"t = {t[k]:.3f} T")
