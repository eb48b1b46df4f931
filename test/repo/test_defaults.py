"""Defaults are written once: each node's parameter table (Param) takes them from the core's dataclass or
constants, a params file under config/ sets only what differs from them, and the offline loop and the sweeps
default to the same values; config/ is installed into quad_bringup's share directory."""

import dataclasses
import importlib
import inspect
import subprocess
import sys

import numpy as np
import pytest

from quad_bringup.experiments import runs
from quad_bringup.offline import closed_loop
from quad_bringup.offline.closed_loop import LoopOptions
from quad_common import paths
from quad_common.params import parameters_of
from quad_common.paths import resolve_config
from quad_common.yaml_io import load_yaml
from quad_control.position import PositionGains

NODES = [  # (module, parameter table, node name, its params file under config/)
    ('quad_control.parameters', 'SPECS', 'position_controller', 'config/control.yaml'),
    ('quad_sim.parameters', 'SPECS', 'sim_node', 'config/sim.yaml'),
    ('quad_trajectory.trajectory_node', 'SPECS', 'trajectory_node', 'config/trajectory.yaml'),
    ('quad_bridge.parameters', 'SPECS', 'mavlink_bridge', 'config/bridge_px4.yaml'),
    ('quad_bridge.parameters', 'SPECS', 'mavlink_bridge', 'config/bridge_ardupilot.yaml'),
]


@pytest.mark.parametrize(('module', 'table', 'node', 'config'), NODES)
def test_params_files_set_only_what_differs_from_the_node_defaults(module, table, node, config):
    """A default is written once, in the node's table: a params file under config/ sets only parameters of its node,
    each to a value other than the default (the docs tables list every parameter: test_parameter_docs)."""
    specs = {p.name: p for p in getattr(importlib.import_module(module), table)}
    values = parameters_of(load_yaml(resolve_config(config)), node)
    assert not set(values) - set(specs), f'{config}: not parameters of {node}: {set(values) - set(specs)}'
    repeated = sorted(name for name, value in values.items() if value == specs[name].default)
    assert not repeated, f'{config} repeats the node defaults of {repeated}: leave them to the node\'s table'


def test_controller_parameters_default_to_the_dataclass():
    from quad_control.parameters import SPECS
    specs = {p.name: p.default for p in SPECS}
    gains = PositionGains()
    for field in dataclasses.fields(PositionGains):
        value = getattr(gains, field.name)
        if isinstance(value, np.ndarray):
            assert [specs[f'{field.name}_{a}'] for a in 'xyz'] == value.tolist(), field.name
        else:
            assert specs[field.name] == value, field.name
    options = LoopOptions()
    assert (specs['rate_hz'], specs['max_start_step_m']) == (options.rate_hz, options.max_start_step_m)


def test_bridge_parameters_default_to_the_bridge_config():
    """BridgeConfig's fields are mavlink_bridge's parameters of the same name (angle_boost apart: read from the
    vehicle), and the parameters default to them."""
    from quad_bridge.backend import BridgeConfig
    from quad_bridge.parameters import SPECS
    specs = {p.name: p.default for p in SPECS}
    fields = {f.name: f.default for f in dataclasses.fields(BridgeConfig) if f.name != 'angle_boost'}
    assert set(fields) <= set(specs), sorted(set(fields) - set(specs))
    assert fields == {name: specs[name] for name in fields}


def test_simulator_defaults_are_sim_nodes():
    """Simulator's keyword defaults of the same name and meaning, the offline loop's and a sweep's are sim_node's;
    one lockstep step is one controller period."""
    from quad_control.parameters import SPECS as CONTROL
    from quad_sim.parameters import SPECS
    from quad_sim.simulator import Simulator
    specs = {p.name: p.default for p in SPECS}
    keywords = inspect.signature(Simulator).parameters
    for name in ('physics_rate_hz', 'initial_yaw', 'robot_radius_m', 'seed', 'setpoint_timeout_s'):
        assert keywords[name].default == specs[name], f'Simulator {name} = {keywords[name].default!r}, ' \
                                                      f'sim_node\'s {specs[name]!r}'
    assert LoopOptions().physics_rate_hz == specs['physics_rate_hz'] == runs.loop_defaults()['physics_rate_hz']
    rate_hz = {p.name: p.default for p in CONTROL}['rate_hz']
    assert specs['lockstep_period_s'] == pytest.approx(1.0 / rate_hz)


def test_offline_loop_and_sweeps_default_to_the_nodes():
    from quad_control.parameters import SPECS as CONTROL
    from quad_trajectory.trajectory_node import SPECS
    assert closed_loop.SAMPLE_RATE_HZ == {p.name: p.default for p in SPECS}['sample_rate_hz']
    control = {p.name: p.default for p in CONTROL}
    loop = runs.loop_defaults()
    options = LoopOptions()
    assert loop['rate_hz'] == options.rate_hz == control['rate_hz']
    assert (loop['time_limit_factor'], loop['position_tolerance_m'], loop['speed_tolerance_mps']) == (
        options.time_limit_factor, options.rule.position_tolerance_m, options.rule.speed_tolerance_mps)


def test_this_workspace_installs_every_config_file():
    """quad_bringup's setup.py installs config/ (all of it) into its share directory."""
    share = paths.share_dir()
    if share is None:
        pytest.fail('quad_bringup is not installed (source install/setup.bash): its share directory is missing')
    source = sorted(p.relative_to(paths.REPO_ROOT) for p in (paths.REPO_ROOT / 'config').rglob('*.*'))
    assert source and all((share / p).is_file() for p in source)


def test_parameter_tables_and_profiles_import_without_rclpy():
    """The controller's table, the params-file helpers and the profile readers are ROS-free cores."""
    code = ("import sys; sys.modules.update(rclpy=None, rcl_interfaces=None); "
            "import quad_common.params, quad_control.parameters; "
            "from quad_bringup.offline import closed_loop; from quad_bringup.experiments import runs; "
            "runs.default_gains(); closed_loop.load_control_profile('config/control_fast.yaml')")
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, cwd=paths.REPO_ROOT)
    assert done.returncode == 0, done.stderr
