"""`quadflight sweep SPEC.yaml`: many flights over missions x controllers x vehicles (plant family) x
disturbances x seeds, as a grid or a random sample of it (docs/quad_bringup.md "Many flights").

Output directory: runs.jsonl (one row per run, appended as each finishes: the resume key and the source of the
other files), runs.csv (the same rows flat), summary.csv/.md (per configuration over its seeds: median, p95 and
worst RMSE, failures) and figures/ (RMSE distribution per controller, error vs wind speed).

numpy is imported by the functions that use it: a spec refused for its file says so without it.
"""

import csv
import itertools
import json
import math
from pathlib import Path

import yaml

from quad_bringup.experiments import runs
from quad_bringup.experiments.runs import SpecError
from quad_common.yaml_io import load_yaml

SPEC_KEYS = ('sample', 'samples', 'seed', 'missions', 'controllers', 'vehicles', 'disturbances', 'seeds', 'options')
CONFIG_COLUMNS = ('mission', 'speed_mps', 'controller_name', 'vehicle_name', 'disturbance_name')


def load_spec(path) -> dict:
    try:
        spec = load_yaml(path)
    except (OSError, yaml.YAMLError) as exc:
        raise SpecError(f'spec {path}: {exc}') from None
    except ValueError as exc:   # load_yaml's: it names the file (not there, not YAML, not a mapping)
        raise SpecError(f'spec {exc}') from None
    if not isinstance(spec, dict):
        raise SpecError(f'spec {path}: must be a mapping (missions, controllers, vehicles, disturbances, seeds)')
    return spec


def expand(spec: dict, mode: str = 'offline', where: str = 'spec') -> list[dict]:
    """Every run's parameters: the grid of the spec's axes, or `samples` of its points drawn (without
    replacement) with `seed`. Raises SpecError naming a bad field."""
    unknown = set(spec) - set(SPEC_KEYS)
    if unknown:
        raise SpecError(f'{where}: unknown key(s) {sorted(unknown)}; known: {", ".join(SPEC_KEYS)}')
    if spec.get('vehicles') == 'plant_family':  # every member of config/plant_family.yaml
        from quad_common.vehicle_file import load_plant_family

        spec = {**spec, 'vehicles': list(load_plant_family())}
    axes = [runs.entries(spec, 'missions', runs.mission_entry, None),
            runs.entries(spec, 'controllers', runs.controller_entry, ['pd']),
            runs.entries(spec, 'vehicles', runs.vehicle_entry, [None]),
            runs.entries(spec, 'disturbances', runs.disturbance_entry, ['none']),
            runs.seeds_entry(spec.get('seeds', 1), 'seeds')]
    options = runs.loop_options(spec.get('options'), 'options')
    fleets = [i for i, m in enumerate(axes[0]) if m.get('fleet')]
    if mode == 'graph' and fleets:
        raise SpecError(f'missions[{fleets[0]}]: {axes[0][fleets[0]]["mission"]} is a fleet mission: '
                        + runs.GRAPH_FLEET_REFUSAL)
    for key, axis in zip(('controllers', 'vehicles', 'disturbances'), axes[1:4]):
        names = [entry[0] for entry in axis]
        if len(set(names)) != len(names):
            raise SpecError(f'{key}: names must differ, got {names} (give each entry a `name`)')
    grid = list(itertools.product(*axes))
    sample = spec.get('sample', 'grid')
    if sample == 'random':
        n = spec.get('samples')
        if not (isinstance(n, int) and not isinstance(n, bool) and n > 0):
            raise SpecError(f'samples = {n!r} must be an integer > 0 with sample: random')
        seed = spec.get('seed', 0)
        if not isinstance(seed, int) or isinstance(seed, bool):
            raise SpecError(f'seed = {seed!r} must be an integer')
        import numpy as np

        rng = np.random.default_rng(seed)
        grid = [grid[i] for i in sorted(rng.choice(len(grid), size=min(n, len(grid)), replace=False))]
    elif sample != 'grid':
        raise SpecError(f"sample = {sample!r} must be 'grid' or 'random'")
    return [runs.make_params(*point, options=options, mode=mode) for point in grid]


# --- the table ------------------------------------------------------------------------------------------------

def read_rows(out_dir) -> list[dict]:
    """Rows of runs.jsonl (a line cut short by a kill is skipped: that run is flown again)."""
    path = Path(out_dir) / 'runs.jsonl'
    rows = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return rows


def _csv_value(value):
    if isinstance(value, (dict, list)):
        return json.dumps(value, sort_keys=True)
    return '' if value is None else value


class RunTable:
    """Appends each finished row to runs.jsonl and runs.csv at once (flushed), so nothing finished is lost."""

    def __init__(self, out_dir):
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.done = {row['key']: row for row in read_rows(self.out_dir)}
        csv_path = self.out_dir / 'runs.csv'
        new_csv = not csv_path.exists() or csv_path.stat().st_size == 0
        self._jsonl = open(self.out_dir / 'runs.jsonl', 'a')
        self._csv_file = open(csv_path, 'a', newline='')
        columns = runs.ROW_COLUMNS
        if not new_csv:   # resuming a table an older version started: append under its own header
            with open(csv_path, newline='') as f:
                columns = next(csv.reader(f), None) or columns
        self._columns = columns
        self._csv = csv.DictWriter(self._csv_file, columns, extrasaction='ignore')
        if new_csv:
            self._csv.writeheader()

    def append(self, row: dict):
        self._jsonl.write(json.dumps(row, sort_keys=True, default=float) + '\n')
        self._jsonl.flush()
        self._csv.writerow({k: _csv_value(row.get(k)) for k in self._columns})
        self._csv_file.flush()
        self.done[row['key']] = row

    def close(self):
        self._jsonl.close()
        self._csv_file.close()


def execute(params_list: list[dict], table: RunTable, executor, label: str, graph_dir=None) -> list[dict]:
    """Flies the runs not yet in the table through the executor, appending each row as it finishes; returns
    the rows of params_list (resumed and new), in its order. Ctrl-C keeps every row already appended."""
    from quad_bringup.pools.executors import Progress

    keys = [runs.run_key(p) for p in params_list]
    todo = {}
    for key, params in zip(keys, params_list):
        if key not in table.done:
            todo.setdefault(key, params)
    progress = Progress(len(todo), label, already=len(set(keys)) - len(todo))
    try:
        todo_list = list(todo.values())
        for i, result in executor.map_unordered(runs.run_one, todo_list, graph_dir):
            if isinstance(result, BaseException):  # the worker itself failed (run_one catches a run's errors)
                if isinstance(result, KeyboardInterrupt):
                    raise result
                result = _worker_failure(todo_list[i], result)
            table.append(result)
            progress.update(result['failed'])
    finally:
        progress.close()
    return [table.done[k] for k in keys]


def _worker_failure(params, exc) -> dict:
    row = {c: None for c in runs.ROW_COLUMNS}
    row.update(key=runs.run_key(params), mode=params['mode'], mission=Path(params['mission']).stem,
               speed_mps=params['speed_mps'], controller_name=params['controller_name'],
               controller=params['gains']['controller'], vehicle_name=params['vehicle_name'],
               disturbance_name=params['disturbance_name'], seed=params['seed'], failed=True,
               failure=f'worker: {type(exc).__name__}: {exc}', params=params)
    return row


# --- summary and figures --------------------------------------------------------------------------------------

def _stats(values):
    import numpy as np

    values = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if not len(values):
        return None, None, None
    return float(np.median(values)), float(np.percentile(values, 95)), float(np.max(values))


def summarize(rows: list[dict]) -> list[dict]:
    """Per configuration (mission, speed, controller, vehicle, disturbance) over its seeds: RMSE median, p95,
    worst (of the runs that have one), the worst max error, the median time over plan, failures. With fleet rows
    among them (a fleet mission's row: its worst vehicle's errors), also the vehicle-vehicle collisions and the
    smallest flown separation (empty for single-vehicle configurations)."""
    fleets = any(r.get('fleet_size') for r in rows)
    groups = {}
    for row in rows:
        groups.setdefault(tuple(row[c] for c in CONFIG_COLUMNS), []).append(row)
    summary = []
    for config, group in groups.items():
        median, p95, worst = _stats([r['rmse_m'] for r in group])
        summary.append({**dict(zip(CONFIG_COLUMNS, config)), 'runs': len(group),
                        'failures': sum(bool(r['failed']) for r in group),
                        'rmse_median_m': median, 'rmse_p95_m': p95, 'rmse_worst_m': worst,
                        'max_error_worst_m': _stats([r['max_error_m'] for r in group])[2],
                        'time_over_median_s': _stats([r['time_over_s'] for r in group])[0]})
        if fleets:
            fleet = [r for r in group if r.get('fleet_size')]
            separations = [r['min_separation_m'] for r in fleet if r.get('min_separation_m') is not None]
            flown = [r['vehicle_collisions'] for r in fleet if r.get('vehicle_collisions') is not None]
            summary[-1].update(vehicles=max((r['fleet_size'] for r in fleet), default=None),
                               vehicle_collisions=sum(flown) if flown else None,   # None: none flown (refused)
                               min_separation_m=min(separations) if separations else None)
    return summary


SUMMARY_FORMATS = {'rmse_median_m': '{:.4f}', 'rmse_p95_m': '{:.4f}', 'rmse_worst_m': '{:.4f}',
                   'max_error_worst_m': '{:.4f}', 'time_over_median_s': '{:.2f}', 'min_separation_m': '{:.3f}'}


def summary_markdown(summary: list[dict]) -> str:
    if not summary:
        return '_no runs_\n'
    columns = list(summary[0])
    lines = ['| ' + ' | '.join(columns) + ' |', '|' + '|'.join('---' for _ in columns) + '|']
    for s in summary:
        cells = ['-' if s[c] is None else SUMMARY_FORMATS.get(c, '{}').format(s[c]) for c in columns]
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def write_summary(out_dir, rows: list[dict]) -> list[dict]:
    out_dir = Path(out_dir)
    summary = summarize(rows)
    with open(out_dir / 'summary.csv', 'w', newline='') as f:
        if summary:
            writer = csv.DictWriter(f, list(summary[0]))
            writer.writeheader()
            writer.writerows({k: '' if v is None else v for k, v in s.items()} for s in summary)
    (out_dir / 'summary.md').write_text(summary_markdown(summary))
    return summary


def draw_figures(out_dir, rows: list[dict]) -> list[Path]:
    """figures/rmse_by_controller.png (box per controller over every run; failures counted in the label) and
    figures/error_vs_wind.png (RMSE against |wind| per controller)."""
    import matplotlib
    import numpy as np
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig_dir = Path(out_dir) / 'figures'
    fig_dir.mkdir(parents=True, exist_ok=True)
    names = sorted({r['controller_name'] for r in rows})
    ok = {n: [r for r in rows if r['controller_name'] == n and r['rmse_m'] is not None] for n in names}
    paths = []
    fig, ax = plt.subplots(figsize=(max(4.0, 1.6 * len(names)), 4))
    ax.boxplot([[r['rmse_m'] for r in ok[n]] or [np.nan] for n in names], whis=(5, 95), showfliers=True)
    ax.set_xticks(range(1, len(names) + 1), [
        f'{n}\n{sum(r["failed"] for r in rows if r["controller_name"] == n)} failed' for n in names])
    ax.set_yscale('log')
    ax.set_ylabel('RMSE (m)')
    ax.set_title(f'RMSE per controller, {len(rows)} runs', fontsize=10)
    ax.grid(True, which='both', alpha=0.3)
    fig.tight_layout()
    paths.append(fig_dir / 'rmse_by_controller.png')
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4))
    span = max([r['wind_speed_mps'] for r in rows] + [1.0])
    for i, n in enumerate(names):  # side by side at each wind speed; failed runs as crosses
        dx = (i - (len(names) - 1) / 2) * 0.025 * span
        for failed, marker in ((False, 'o'), (True, 'x')):
            mine = [r for r in ok[n] if bool(r['failed']) == failed]
            ax.scatter([r['wind_speed_mps'] + dx for r in mine], [r['rmse_m'] for r in mine], s=14, alpha=0.7,
                       marker=marker, color=f'C{i}', label=n if not failed else None)
    ax.set_xlabel('wind speed |wind_mps| (m/s)')
    ax.set_ylabel('RMSE (m)')
    ax.set_yscale('log')
    ax.set_title('Tracking error vs wind speed (x: failed runs)')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    paths.append(fig_dir / 'error_vs_wind.png')
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def run_sweep(spec_path, out_dir, mode: str = 'offline', scheduler: str | None = None,
              workers: int | None = None, figures: bool = True, log=print) -> tuple[list[dict], list[dict]]:
    """Expands the spec, flies what is not yet in out_dir, writes summary and figures; returns (rows, summary)."""
    from quad_bringup.experiments.outputs import OutputDir, check_out_dir
    from quad_bringup.pools.executors import make_executor

    spec = load_spec(spec_path)
    params_list = expand(spec, mode)
    out_dir = Path(out_dir)
    check_out_dir(out_dir)
    executor = make_executor(scheduler, workers)   # a refused pool or scheduler leaves nothing behind
    try:
        lock = OutputDir(out_dir, 'sweep')
    except SpecError:
        executor.close()
        raise
    try:
        (out_dir / 'spec.yaml').write_text(yaml.safe_dump(spec, sort_keys=False))
        table = RunTable(out_dir)
        log(f'sweep: {len(params_list)} runs ({mode}) on {executor.description} -> {out_dir}')
        try:
            rows = execute(params_list, table, executor, 'sweep', graph_dir=str(out_dir / 'graph') if
                           mode == 'graph' else None)
        finally:
            table.close()
    finally:
        executor.close()
        lock.close()
    summary = write_summary(out_dir, rows)
    if figures:
        draw_figures(out_dir, rows)
    return rows, summary
