"""Defaults are written once: each node's parameter table (Param) takes them from the core's dataclass or
constants, and the node's YAML under config/ lists every parameter with exactly that default; config/ is
installed into quad_bringup's share directory."""

import dataclasses
import importlib
import subprocess
import sys

import numpy as np
import pytest

from quad_bringup.closed_loop import LoopOptions
from quad_common import paths
from quad_common.params import parameters_of
from quad_common.paths import resolve_config
from quad_common.yaml_io import load_yaml
from quad_control.position import PositionGains

NODES = [  # (module, parameter table, node name, its YAML)
    ('quad_control.parameters', 'SPECS', 'position_controller', 'config/control.yaml'),
    ('quad_sim.sim_node', 'SPECS', 'sim_node', 'config/sim.yaml'),
    ('quad_trajectory.trajectory_node', 'PARAMS', 'trajectory_node', 'config/trajectory.yaml'),
]


@pytest.mark.parametrize(('module', 'table', 'node', 'config'), NODES)
def test_yaml_lists_every_parameter_with_its_default(module, table, node, config):
    specs = {p.name: p for p in getattr(importlib.import_module(module), table)}
    values = parameters_of(load_yaml(resolve_config(config)), node)
    assert not set(values) - set(specs), f'{config}: not parameters of {node}: {set(values) - set(specs)}'
    with_default = {name for name, p in specs.items() if isinstance(p.default, (bool, int, float, str, list))}
    assert with_default <= set(values), f'{config} leaves out {sorted(with_default - set(values))}'
    for name in with_default:
        assert values[name] == specs[name].default, f'{config}: {name} = {values[name]!r}, ' \
                                                    f'the node default is {specs[name].default!r}'


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
            "import quad_common.params, quad_control.parameters; from quad_bringup import closed_loop, runs; "
            "runs.default_gains(); closed_loop.load_control_profile('config/control_fast.yaml')")
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, cwd=paths.REPO_ROOT)
    assert done.returncode == 0, done.stderr
