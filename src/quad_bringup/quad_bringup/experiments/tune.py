"""`quadflight tune SPEC.yaml`: search a controller's gains (and attitude lead / disturbance observer settings)
for the lowest robust cost over a mission set and a plant family, then verify the best profile through the graph.

Cost of one run (m):  c = divergence_m                                            if it failed (not completed,
                                                                                   collided, stopped, raised)
                      c = rmse + tilt_weight_m_per_deg * max(0, max_tilt - tilt_limit_deg)
                            + saturation_weight_m * (fraction of ticks with thrust or tilt clamped)  otherwise
Cost of a profile:    J = p95 (or worst, or mean: cost.aggregate) of c over missions x vehicles x disturbances
                      x seeds.
Optimiser: scipy.optimize.differential_evolution (already a dependency, maintained with SciPy, derivative-free and
global, which a cost with failure plateaus needs). Its `vectorized` mode hands over a whole generation at once, so
every candidate x every run of a generation goes to the executor (process pool or Dask) as one batch; the starting
profile is put into the first generation (x0), so "before" is measured in the same run.
"""

import csv
import json
import math
from pathlib import Path

import numpy as np
import yaml

from quad_bringup.experiments import runs, sweep
from quad_bringup.experiments.runs import SpecError

SPEC_KEYS = ('controller', 'parameters', 'missions', 'vehicles', 'disturbances', 'seeds', 'options', 'cost',
             'optimizer', 'verify')
COST_DEFAULTS = {'aggregate': 'p95', 'divergence_m': 1.0, 'tilt_limit_deg': 30.0, 'tilt_weight_m_per_deg': 0.01,
                 'saturation_weight_m': 0.1}
AGGREGATES = {'p95': lambda c: float(np.percentile(c, 95)), 'worst': lambda c: float(np.max(c)),
              'mean': lambda c: float(np.mean(c))}
OPTIMIZER_DEFAULTS = {'maxiter': 10, 'popsize': 5, 'seed': 0, 'tol': 0.01, 'mutation': [0.5, 1.0],
                      'recombination': 0.7}


def run_cost(row: dict, cost: dict) -> float:
    """c of one run (module docstring)."""
    if row['failed'] or row['rmse_m'] is None or not math.isfinite(row['rmse_m']):
        return float(cost['divergence_m'])
    tilt = max(0.0, (row['max_tilt_deg'] or 0.0) - cost['tilt_limit_deg'])
    return float(row['rmse_m'] + cost['tilt_weight_m_per_deg'] * tilt
                 + cost['saturation_weight_m'] * (row['saturated_fraction'] or 0.0))


def _mapping(spec, key, defaults):
    value = spec.get(key) or {}
    if not isinstance(value, dict) or set(value) - set(defaults):
        raise SpecError(f'{key} = {value!r} must be a mapping with keys from {", ".join(defaults)}')
    return {**defaults, **value}


def parse_parameters(entry, base: dict) -> list[tuple[str, tuple[str, ...], float, float]]:
    """[(name, profile keys, low, high)]: `kp_xy` sets kp_x and kp_y together; the base profile's value must lie
    within the bounds (it is the starting point)."""
    if not isinstance(entry, dict) or not entry:
        raise SpecError(f'parameters = {entry!r} must map controller keys to [low, high]')
    out = []
    for name, bounds in entry.items():
        keys = (f'{name[:-3]}_x', f'{name[:-3]}_y') if name.endswith('_xy') else (name,)
        for key in keys:
            if key not in runs.GAIN_KEYS or key in ('controller', 'use_feedforward'):
                raise SpecError(f'parameters.{name}: {key!r} is not a numeric controller key; known: '
                                f'{", ".join(k for k in runs.GAIN_KEYS if k not in ("controller", "use_feedforward"))}'
                                ' (and kp_xy, kd_xy, ki_xy)')
        ok = (isinstance(bounds, list) and len(bounds) == 2 and all(
            isinstance(b, (int, float)) and not isinstance(b, bool) and math.isfinite(b) for b in bounds)
            and bounds[0] < bounds[1])
        if not ok:
            raise SpecError(f'parameters.{name} = {bounds!r} must be [low, high] with low < high')
        for key in keys:
            runs.check_gain(key, float(bounds[0]), f'parameters.{name}')
            runs.check_gain(key, float(bounds[1]), f'parameters.{name}')
        start = base[keys[0]]
        if not bounds[0] <= start <= bounds[1]:
            raise SpecError(f'parameters.{name} = {bounds!r} must contain the starting profile\'s {keys[0]} = '
                            f'{start}')
        out.append((name, keys, float(bounds[0]), float(bounds[1])))
    return out


def check_optimizer(options: dict) -> dict:
    """differential_evolution's settings within what it accepts (it runs even with maxiter -1, so we refuse it)."""
    def number(key, low, high, integer=False, low_inclusive=True):
        value = options[key]
        kind = int if integer else (int, float)
        ok = isinstance(value, kind) and not isinstance(value, bool) and math.isfinite(value) and (
            low <= value if low_inclusive else low < value) and value <= high
        if not ok:
            raise SpecError(f'optimizer.{key} = {value!r} refused: must be {"an integer" if integer else "a number"} '
                            f'{">=" if low_inclusive else ">"} {low:g} and <= {high:g}')
    number('maxiter', 1, 1e6, integer=True)
    number('popsize', 1, 1e4, integer=True)
    number('seed', 0, 2**32 - 1, integer=True)
    number('tol', 0.0, 1e6)
    number('recombination', 0.0, 1.0)
    mutation = options['mutation']
    values = mutation if isinstance(mutation, list) else [mutation]
    ok = len(values) in (1, 2) and all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v < 2.0
                                       for v in values) and (len(values) == 1 or values[0] <= values[1])
    if not ok:
        raise SpecError(f'optimizer.mutation = {mutation!r} refused: must be a number or [low, high] in [0, 2)')
    return options


class Tuning:
    """The parsed spec and the evaluation log (one entry per candidate profile evaluated)."""

    def __init__(self, spec: dict, out_dir: Path, executor):
        unknown = set(spec) - set(SPEC_KEYS)
        if unknown:
            raise SpecError(f'tune spec: unknown key(s) {sorted(unknown)}; known: {", ".join(SPEC_KEYS)}')
        self.name, self.base = runs.controller_entry(spec.get('controller', 'se3'), 'controller')
        self.parameters = parse_parameters(spec.get('parameters'), self.base)
        self.cost = _mapping(spec, 'cost', COST_DEFAULTS)
        if self.cost['aggregate'] not in AGGREGATES:
            raise SpecError(f'cost.aggregate = {self.cost["aggregate"]!r} must be one of {", ".join(AGGREGATES)}')
        self.optimizer = check_optimizer(_mapping(spec, 'optimizer', OPTIMIZER_DEFAULTS))
        self.verify = spec.get('verify', True)
        # the plant family and mission set: a sweep spec of one controller (validated the same way)
        grid = {k: spec[k] for k in ('missions', 'vehicles', 'disturbances', 'seeds', 'options') if k in spec}
        self.family = sweep.expand({**grid, 'controllers': [{'name': self.name, 'gains': self.base}]})
        self.out_dir, self.executor = out_dir, executor
        self.table = None   # run_tune opens it once the spec is accepted and the directory is ours
        self.evaluations = []
        self.calls = 0

    def gains_of(self, x) -> dict:
        gains = dict(self.base)
        for (_, keys, _, _), value in zip(self.parameters, x):
            for key in keys:  # 12 digits: the optimiser's unscaling (0.05 -> 0.049999999999999996) keeps one key
                gains[key] = float(f'{float(value):.12g}')
        return gains

    def x0(self) -> np.ndarray:
        return np.array([self.base[keys[0]] for _, keys, _, _ in self.parameters])

    def runs_of(self, gains: dict, label: str, mode='offline', family=None) -> list[dict]:
        return [{**p, 'controller_name': label, 'gains': gains, 'mode': mode} for p in (family or self.family)]

    def evaluate(self, xs: np.ndarray) -> np.ndarray:
        """Costs of candidates xs (S, N): all their runs as one batch through the executor."""
        candidates = [self.gains_of(x) for x in xs]
        # a candidate's label is a hash of its gains: the same profile twice (x0, a rerun) reuses its rows
        batches = [self.runs_of(g, f'{self.name}@{runs.run_key(g)[:8]}') for g in candidates]
        generation = self.calls
        self.calls += 1
        rows = sweep.execute([p for batch in batches for p in batch], self.table, self.executor,
                             f'tune generation {generation}')
        costs = []
        for i, (x, batch) in enumerate(zip(xs, batches)):
            mine = rows[i * len(batch):(i + 1) * len(batch)]
            c = np.array([run_cost(r, self.cost) for r in mine])
            cost = AGGREGATES[self.cost['aggregate']](c)
            rmse = [r['rmse_m'] for r in mine if r['rmse_m'] is not None]
            best = min([e['cost'] for e in self.evaluations] + [cost])
            self.evaluations.append({
                'evaluation': len(self.evaluations), 'generation': generation,
                **{name: float(v) for (name, _, _, _), v in zip(self.parameters, x)}, 'cost': cost,
                'rmse_median_m': float(np.median(rmse)) if rmse else None,
                'rmse_worst_m': float(np.max(rmse)) if rmse else None,
                'failures': int(sum(bool(r['failed']) for r in mine)),
                'max_tilt_deg': max((r['max_tilt_deg'] or 0.0) for r in mine),
                'saturated_fraction_max': max((r['saturated_fraction'] or 0.0) for r in mine),
                'best_so_far': best, 'run_keys': [r['key'] for r in mine]})
            costs.append(cost)
        self._write_evaluations()
        return np.array(costs)

    def _write_evaluations(self):
        columns = [c for c in self.evaluations[0] if c != 'run_keys']
        with open(self.out_dir / 'evaluations.csv', 'w', newline='') as f:
            writer = csv.DictWriter(f, columns, extrasaction='ignore')
            writer.writeheader()
            writer.writerows({k: '' if v is None else v for k, v in e.items()} for e in self.evaluations)

    def optimise(self):
        from scipy.optimize import differential_evolution

        o = self.optimizer
        bounds = [(lo, hi) for _, _, lo, hi in self.parameters]
        before = float(self.evaluate(self.x0()[None, :])[0])  # the starting profile, alone: cost "before"
        result = differential_evolution(
            lambda x: self.evaluate(np.atleast_2d(x.T)), bounds, x0=self.x0(), vectorized=True,
            updating='deferred', maxiter=int(o['maxiter']), popsize=int(o['popsize']), seed=int(o['seed']),
            tol=float(o['tol']), mutation=tuple(o['mutation']), recombination=float(o['recombination']),
            polish=False, init='latinhypercube')
        best_gains = self.gains_of(result.x)
        return before, float(result.fun), best_gains, result


def write_profile(path: Path, gains: dict, header: str):
    from quad_control.parameters import profile_content

    body = yaml.safe_dump(profile_content(gains), sort_keys=False)
    path.write_text(''.join(f'# {line}\n' for line in header.splitlines()) + body)


def run_tune(spec_path, out_dir, scheduler=None, workers=None, verify=None, log=print) -> dict:
    """Tunes, writes profile.yaml, cost.json, evaluations.csv (+ runs.csv/.jsonl) and, unless verify is False,
    verify.md (the best profile through the ROS graph on the mission set beside its offline result)."""
    from quad_bringup.experiments.outputs import OutputDir, check_out_dir
    from quad_bringup.pools.executors import make_executor

    spec = sweep.load_spec(spec_path)
    out_dir = Path(out_dir)
    check_out_dir(out_dir)
    executor = make_executor(scheduler, workers)
    lock = None
    try:
        tuning = Tuning(spec, out_dir, executor)   # the spec checked before anything is written
        lock = OutputDir(out_dir, 'tune')
        (out_dir / 'spec.yaml').write_text(yaml.safe_dump(spec, sort_keys=False))
        tuning.table = sweep.RunTable(out_dir)
        log(f'tune: {tuning.name} ({", ".join(p[0] for p in tuning.parameters)}) over {len(tuning.family)} runs '
            f'per candidate on {executor.description} -> {out_dir}')
        before, after, best, result = tuning.optimise()
        summary = {'controller': tuning.name, 'aggregate': tuning.cost['aggregate'], 'cost_before_m': before,
                   'cost_after_m': after, 'evaluations': len(tuning.evaluations),
                   'runs': len(tuning.evaluations) * len(tuning.family), 'generations': int(result.nit),
                   'optimizer': 'scipy.optimize.differential_evolution', 'optimizer_message': result.message,
                   'base_gains': tuning.base, 'best_gains': best, 'cost': tuning.cost,
                   'versions': runs.versions()}
        if after > before:  # DE keeps x0 in its population, so this only happens with a noisy cost
            best, summary['best_gains'], summary['cost_after_m'] = tuning.base, tuning.base, before
        write_profile(out_dir / 'profile.yaml', best,
                      f'quadflight tune {spec_path}: {tuning.cost["aggregate"]} cost {before:.4f} m -> '
                      f'{summary["cost_after_m"]:.4f} m over {len(tuning.family)} runs\n'
                      f'evaluations: evaluations.csv, runs: runs.csv (beside this file)\n'
                      f'use: quadflight fly MISSION --control-profile {out_dir / "profile.yaml"}')
        if verify if verify is not None else tuning.verify:
            summary['verify'] = verify_graph(tuning, best, out_dir, log)
        (out_dir / 'cost.json').write_text(json.dumps(summary, indent=2, default=str) + '\n')
    finally:
        executor.close()
        if 'tuning' in locals() and tuning.table is not None:
            tuning.table.close()
        if lock is not None:
            lock.close()
    return summary


def verify_graph(tuning: Tuning, gains: dict, out_dir: Path, log) -> list[dict]:
    """The best profile on each mission (first vehicle, disturbance and seed of the spec) through the ROS graph
    and offline; verify.md puts them side by side."""
    first = tuning.family[0]
    family = [p for p in tuning.family if (p['vehicle_name'], p['disturbance_name'], p['seed']) ==
              (first['vehicle_name'], first['disturbance_name'], first['seed'])]
    offline = tuning.runs_of(gains, 'best', family=family)
    graph = tuning.runs_of(gains, 'best', mode='graph', family=family)
    log(f'tune: verifying the best profile through the ROS graph on {len(graph)} missions')
    rows = sweep.execute(offline + graph, tuning.table, tuning.executor, 'verify', graph_dir=str(out_dir / 'graph'))
    n = len(offline)
    report = [{'mission': o['mission'], 'speed_mps': o['speed_mps'], 'offline_rmse_m': o['rmse_m'],
               'graph_rmse_m': g['rmse_m'], 'offline_time_actual_s': o['time_actual_s'],
               'graph_time_actual_s': g['time_actual_s'], 'graph_completed': not g['failed'],
               'graph_failure': g['failure']} for o, g in zip(rows[:n], rows[n:])]
    lines = ['| mission | speed (m/s) | RMSE offline (m) | RMSE graph (m) | time offline (s) | time graph (s) | '
             'graph |', '|---|---:|---:|---:|---:|---:|---|']
    fmt = lambda v, f: '-' if v is None else f.format(v)  # noqa: E731
    for r in report:
        lines.append(f'| {r["mission"]} | {fmt(r["speed_mps"], "{:.1f}")} | {fmt(r["offline_rmse_m"], "{:.4f}")} | '
                     f'{fmt(r["graph_rmse_m"], "{:.4f}")} | {fmt(r["offline_time_actual_s"], "{:.2f}")} | '
                     f'{fmt(r["graph_time_actual_s"], "{:.2f}")} | '
                     f'{"completed" if r["graph_completed"] else r["graph_failure"]} |')
    (out_dir / 'verify.md').write_text('\n'.join(lines) + '\n')
    return report
