"""The report's figures (matplotlib, Agg): the seed's Figures 1-5, error over time and commands; drawn in one
process or split between it and forked children (draw_all's parts)."""

import os
import pickle
import select
import signal
import time
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

AXES = ('x', 'y', 'z')
DESIRED = {'color': 'tab:blue', 'linestyle': '--', 'linewidth': 1.6, 'label': 'desired'}
ACTUAL = {'color': 'tab:red', 'linewidth': 1.2, 'label': 'actual'}
WAYPOINT = {'color': 'black', 'marker': 'o', 's': 22, 'zorder': 5, 'label': 'waypoints'}
OBSTACLE = {'facecolor': 'tab:gray', 'edgecolor': 'dimgray', 'alpha': 0.35}
# fixed subplot margins per figure (figure fractions): what tight_layout gives at these sizes, with room for wider
# tick labels; tight_layout measured every tick label again and was 40 % of the drawing time
MARGINS = {
    'fig1': dict(left=0.06, right=0.985, bottom=0.085, top=0.90, wspace=0.25, hspace=0.16),
    'fig2': dict(left=0.02, right=0.98, bottom=0.04, top=0.95),
    'fig4': dict(left=0.05, right=0.99, bottom=0.11, top=0.87, wspace=0.16),
    'fig5': dict(left=0.065, right=0.98, bottom=0.065, top=0.92, wspace=0.17, hspace=0.19),
    'error': dict(left=0.075, right=0.98, bottom=0.13, top=0.915),
    'commands': dict(left=0.10, right=0.98, bottom=0.06, top=0.96, hspace=0.10),
}


def _series(flight):
    """Flight time since trajectory start, actual and desired position/velocity at the odometry times."""
    t0 = flight.traj_start_s
    t = flight.odom_t - t0
    desired = flight.trajectory.evaluate(t, order=1)
    return t, desired[0][:, :3], desired[1][:, :3]


def _mark_events(ax, flight):
    ax.axvline(flight.trajectory.duration_s, color='gray', linestyle=':', linewidth=1)
    if flight.collision_time_s is not None:
        ax.axvline(flight.collision_time_s - flight.traj_start_s, color='black', linewidth=1.5)


def fig_position_velocity(flight, path):
    """Seed Figure 1: desired vs actual position and velocity per axis."""
    t, p_des, v_des = _series(flight)
    fig, axes = plt.subplots(2, 3, figsize=(14, 7), sharex=True)
    for i, name in enumerate(AXES):
        for row, (des, act, unit) in enumerate([(p_des, flight.position, 'm'), (v_des, flight.velocity, 'm/s')]):
            ax = axes[row, i]
            ax.plot(t, des[:, i], **DESIRED)
            ax.plot(t, act[:, i], **ACTUAL)
            _mark_events(ax, flight)
            ax.set_title(f'{"position" if row == 0 else "velocity"} {name}')
            ax.set_ylabel(f'{name} ({unit})' if row == 0 else f'v{name} ({unit})')
            ax.grid(True, alpha=0.3)
        axes[1, i].set_xlabel('time since trajectory start (s)')
    axes[0, 0].legend(loc='best')
    fig.suptitle('Desired vs actual position and velocity (dotted line: planned end)')
    return _save(fig, path, MARGINS['fig1'])


def _box_faces(centre, size):
    lo, hi = centre - size / 2, centre + size / 2
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    idx = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    return [c[list(f)] for f in idx]


def fig_path_3d(flight, path):
    """Seed Figures 2-3: 3D desired and actual path with waypoints and obstacles."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = plt.figure(figsize=(9, 8))
    ax = fig.add_subplot(projection='3d')
    plan = flight.trajectory.position[:, :3]
    ax.plot(*plan.T, **DESIRED)
    ax.plot(*flight.position.T, **ACTUAL)
    if len(flight.waypoints):
        ax.scatter(*flight.waypoints.T, **WAYPOINT)
    for centre, size in flight.obstacles:
        ax.add_collection3d(Poly3DCollection(_box_faces(centre, size), **OBSTACLE))
    pts = np.vstack([plan, flight.position] + [np.vstack([c - s / 2, c + s / 2]) for c, s in flight.obstacles])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    mid, half = (lo + hi) / 2, max(float(np.max(hi - lo)) / 2, 0.1)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(max(mid[2] - half, lo[2] - 0.1), max(mid[2] - half, lo[2] - 0.1) + 2 * half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    ax.set_zlabel('z (m)')
    ax.legend(loc='upper left')
    ax.set_title('3D path: desired (planned) vs actual' + (', obstacles in gray' if flight.obstacles else ''))
    return _save(fig, path, MARGINS['fig2'])


def fig_plane_views(flight, path):
    """Seed Figure 4: XY, XZ, YZ views with equal aspect."""
    fig, axes = plt.subplots(1, 3, figsize=(16, 5.5))
    plan = flight.trajectory.position[:, :3]
    for ax, (i, j) in zip(axes, [(0, 1), (0, 2), (1, 2)]):
        for centre, size in flight.obstacles:
            ax.add_patch(Rectangle((centre[i] - size[i] / 2, centre[j] - size[j] / 2), size[i], size[j], **OBSTACLE))
        ax.plot(plan[:, i], plan[:, j], **DESIRED)
        ax.plot(flight.position[:, i], flight.position[:, j], **ACTUAL)
        if len(flight.waypoints):
            ax.scatter(flight.waypoints[:, i], flight.waypoints[:, j], **WAYPOINT)
        ax.set_aspect('equal', adjustable='datalim')
        ax.set_xlabel(f'{AXES[i]} (m)')
        ax.set_ylabel(f'{AXES[j]} (m)')
        ax.set_title(f'{AXES[i].upper()}{AXES[j].upper()}-plane view')
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc='best')
    fig.suptitle('Plane-wise views of the desired and actual trajectory')
    return _save(fig, path, MARGINS['fig4'])


def fig_axis_tracking(flight, path):
    """Seed Figure 5: per-axis tracking, with the per-axis error beside it."""
    t, p_des, _ = _series(flight)
    fig, axes = plt.subplots(3, 2, figsize=(14, 9), sharex=True, gridspec_kw={'width_ratios': [2, 1]})
    for i, name in enumerate(AXES):
        ax = axes[i, 0]
        ax.plot(t, p_des[:, i], **DESIRED)
        ax.plot(t, flight.position[:, i], **ACTUAL)
        _mark_events(ax, flight)
        ax.set_ylabel(f'{name} (m)')
        ax.set_title(f'{name}: desired vs actual')
        ax.grid(True, alpha=0.3)
        ax = axes[i, 1]
        ax.plot(t, 100 * (flight.position[:, i] - p_des[:, i]), color='tab:purple', label=f'{name} actual - desired')
        ax.axhline(0, color='gray', linewidth=0.8)
        ax.set_ylabel(f'error {name} (cm)')
        ax.set_title(f'{name} tracking error')
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(loc='best')
    for ax in axes[-1]:
        ax.set_xlabel('time since trajectory start (s)')
    fig.suptitle('X, Y, Z trajectory tracking')
    return _save(fig, path, MARGINS['fig5'])


def fig_error(flight, path):
    """Position error norm over time."""
    t, p_des, _ = _series(flight)
    err = np.linalg.norm(flight.position - p_des, axis=1)
    fig, ax = plt.subplots(figsize=(11, 4.5))
    ax.plot(t, 100 * err, color='tab:red', label='|p actual - p desired|')
    _mark_events(ax, flight)
    ax.set_xlabel('time since trajectory start (s)')
    ax.set_ylabel('position error (cm)')
    ax.set_title('Position tracking error (dotted line: planned end)')
    ax.grid(True, alpha=0.3)
    ax.legend(loc='best')
    return _save(fig, path, MARGINS['error'])


def fig_commands(flight, path):
    """Commanded specific force (thrust / mass) and commanded vs actual attitude."""
    fig, axes = plt.subplots(4, 1, figsize=(11, 10), sharex=True)
    t0 = flight.traj_start_s
    tc = flight.cmd_t - t0
    ax = axes[0]
    if len(tc):
        ax.plot(tc, flight.cmd_specific_force, color='tab:green', label='commanded thrust / mass')
    ax.axhline(9.81, color='gray', linestyle=':', label='g (hover)')
    ax.set_ylabel('specific force (m/s²)')
    ax.set_title('Commanded collective thrust (per unit mass) and attitude')
    ax.legend(loc='best')
    for k, name in enumerate(('roll', 'pitch', 'yaw')):
        ax = axes[k + 1]
        if len(tc):
            ax.plot(tc, np.degrees(flight.cmd_euler[:, k]), color='tab:blue', linestyle='--', label='commanded')
        ax.plot(flight.odom_t - t0, np.degrees(flight.euler[:, k]), color='tab:red', linewidth=1, label='actual')
        ax.set_ylabel(f'{name} (deg)')
        ax.legend(loc='best')
    for ax in axes:
        _mark_events(ax, flight)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel('time since trajectory start (s)')
    return _save(fig, path, MARGINS['commands'])


FIGURES = [
    ('fig1_position_velocity.png', fig_position_velocity),
    ('fig2_path_3d.png', fig_path_3d),
    ('fig4_plane_views.png', fig_plane_views),
    ('fig5_axis_tracking.png', fig_axis_tracking),
    ('error_over_time.png', fig_error),
    ('commands.png', fig_commands),
]


FOLDER = 'figures'   # a run's figures: RUN/figures/*.png (report.md links them)
# Titles at the top of their axes (matplotlib's default, 'axes.titley' None, measures every axis's tick labels
# again to lift a title above top ticks or an offset text these figures do not have: ~10 % of the drawing).
STYLE = {'axes.titley': 1.0}
# at most this many intervals between ticks on a 2-D axis (matplotlib's 'auto': up to 9 on these sizes): each tick
# is ~10 artists made, copied and measured at every draw, ~30 % of the drawing; 5 saves ~11 % of it
TICK_BINS = 5
# zlib level 1: the PNG encoding is ~3x faster than PIL's default 6 for ~8 % larger files
PNG = {'compress_level': 1}


# CPU ms each figure takes to draw for maze (16.7 s flown, 1749 odometry samples; the median of 8 draws in one
# process at load 4): what the parts are balanced by; their ratios, not their sizes, matter
DRAW_MS = {'fig1_position_velocity.png': 390, 'fig2_path_3d.png': 145, 'fig4_plane_views.png': 225,
           'fig5_axis_tracking.png': 375, 'error_over_time.png': 95, 'commands.png': 320}
# parts to draw a run's figures in when the caller has the machine to itself (fly's figure worker after the graph
# stopped, `quadflight report`): every core this process may run on, at most one part per figure
PARTS = min(len(os.sched_getaffinity(0)), len(FIGURES))
# a forked part that has not answered in this long is killed and its figures reported failed: a child that hangs
# must not hang its caller (its part takes ~0.5 s of CPU on maze; this allows for a core shared 20 ways)
PART_TIMEOUT_S = 60.0


def draw_run(flight, run_dir, parts: int = 1) -> list[Path]:
    """A run's figures: run_dir/FOLDER/*.png (parts: as draw_all's)."""
    return draw_all(flight, Path(run_dir) / FOLDER, parts)


def draw_all(flight, out_dir, parts: int = 1) -> list[Path]:
    """FIGURES into out_dir, in FIGURES' order. parts > 1: split by DRAW_MS (split_parts) between this process, which
    draws the first part, and parts - 1 children forked from it, which inherit matplotlib and the flight instead
    of importing or loading them again. Fork it only where no other thread holds a lock the children would need:
    numpy's OpenBLAS stops its own threads before a fork (its atfork handler) and drawing starts none, but a
    process with threads of its own (rclpy's, a pool's) must draw in one part. A part's failure raises in the
    caller: its exception, or ChildProcessError for a child that died or did not answer in PART_TIMEOUT_S; no
    child outlives this call, nor its caller (SIGKILL when the caller dies)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    groups = split_parts([name for name, _ in FIGURES], parts)
    with matplotlib.rc_context(STYLE):
        children = []
        try:
            for group in groups[1:]:
                children.append(_fork_part(flight, out_dir, group))
            drawn = _draw_part(flight, out_dir, groups[0])
            for child in children:
                drawn.update(_answer(child))
        finally:
            for pid, read_end, _ in children:
                os.close(read_end)
                _reap(pid)
    return [drawn[k] for k in sorted(drawn)]


def split_parts(names: list[str], parts: int) -> list[list[int]]:
    """Indices into names in `parts` groups of about equal DRAW_MS: the costliest first, each onto the group with
    the least so far; the costliest group first (the caller keeps it: it starts drawing before a forked child)."""
    groups = [[] for _ in range(max(1, min(parts, len(names))))]
    load = [0] * len(groups)
    for k in sorted(range(len(names)), key=lambda k: -DRAW_MS.get(names[k], 0)):
        g = load.index(min(load))
        groups[g].append(k)
        load[g] += DRAW_MS.get(names[k], 0)
    order = sorted(range(len(groups)), key=lambda g: -load[g])
    return [sorted(groups[g]) for g in order]


def _draw_part(flight, out_dir: Path, indices: list[int]) -> dict[int, Path]:
    return {k: FIGURES[k][1](flight, out_dir / FIGURES[k][0]) for k in indices}


def _fork_part(flight, out_dir: Path, indices: list[int]):
    """(pid, the read end of its answer pipe, the figure names) of a child that draws `indices` and answers one
    pickle: ('drawn', {index: path}) or ('failed', the exception)."""
    from quad_bringup.pools.pool_lifeline import die_with_parent

    parent = os.getpid()
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid:
        os.close(write_end)
        return pid, read_end, [FIGURES[k][0] for k in indices]
    try:   # the child: never returns into the caller's code
        os.close(read_end)
        die_with_parent(parent)
        try:
            answer = pickle.dumps(('drawn', _draw_part(flight, out_dir, indices)))
        except BaseException as exc:   # a signal (KeyboardInterrupt) too is an answer, not a traceback
            try:
                answer = pickle.dumps(('failed', exc))
            except Exception:
                answer = pickle.dumps(('failed', RuntimeError(f'{type(exc).__name__}: {exc}')))
        with os.fdopen(write_end, 'wb') as f:
            f.write(answer)
    finally:
        os._exit(0)


def _answer(child) -> dict[int, Path]:
    """The child's figures once it has exited; raises its exception, or ChildProcessError when it died or hung
    without an answer."""
    pid, read_end, names = child
    deadline = time.monotonic() + PART_TIMEOUT_S
    chunks = []
    while not chunks or chunks[-1]:
        if not select.select([read_end], [], [], max(0.0, deadline - time.monotonic()))[0]:
            raise ChildProcessError(f'the process drawing {", ".join(names)} gave no answer in {PART_TIMEOUT_S:.0f} s')
        chunks.append(os.read(read_end, 1 << 16))
    status = _reap(pid, kill=False)   # its end closed: it is exiting
    if not b''.join(chunks):
        why = f'signal {signal.Signals(-status).name}' if status < 0 else f'exit status {status}'
        raise ChildProcessError(f'the process drawing {", ".join(names)} died ({why}) without an answer')
    what, value = pickle.loads(b''.join(chunks))
    if what == 'failed':
        raise value
    return value


def _reap(pid: int, kill: bool = True) -> int:
    """Wait for a forked part (kill: SIGKILL it first if it is still running); its exit status, -signal if a signal
    ended it, 0 if it was reaped already."""
    try:
        done, status = os.waitpid(pid, os.WNOHANG) if kill else (0, 0)
        if not done:
            if kill:
                os.kill(pid, signal.SIGKILL)
            done, status = os.waitpid(pid, 0)
    except ChildProcessError:
        return 0
    return os.waitstatus_to_exitcode(status)


def _save(fig, path, margins: dict) -> Path:
    for ax in fig.axes:
        if ax.name != '3d':
            ax.xaxis.set_major_locator(MaxNLocator(nbins=TICK_BINS))
            ax.yaxis.set_major_locator(MaxNLocator(nbins=TICK_BINS))
    fig.subplots_adjust(**margins)
    fig.savefig(path, dpi=90, pil_kwargs=PNG)
    plt.close(fig)
    return Path(path)
