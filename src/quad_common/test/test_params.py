import math
import os
import xml.etree.ElementTree as ET

import pytest
import rclpy
from rclpy.parameter import Parameter

from quad_common.params import Param, check_value
from quad_common.ros.ros_params import ParameterSet
from quad_common.ros.testing import FASTDDS_PROFILE, isolated_domain

SPECS = [Param('kp', [5.0, 5.0, 20.0], 'gains', min=0.0, length=3),
         Param('rate_hz', 100.0, 'loop rate', min=1.0, max=1000.0),
         Param('mode', 'pd', 'controller', choices=('pd', 'pid'))]


def test_check_value_names_parameter_and_value():
    assert 'kp = [1.0, -1.0, 2.0] refused: must be >= 0.0' in check_value(SPECS[0], [1.0, -1.0, 2.0])
    assert 'finite' in check_value(SPECS[1], math.nan)
    assert 'one of pd, pid' in check_value(SPECS[2], 'lqr')
    assert check_value(SPECS[0], [1.0, 2.0, 3.0]) is None


@pytest.fixture
def node():
    with isolated_domain() as (domain, _):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=domain)
        n = rclpy.create_node('params_test', context=ctx)
        yield n
        n.destroy_node()
        rclpy.shutdown(context=ctx)


def test_runtime_updates_refused_and_kept(node):
    changes = []
    ps = ParameterSet(node, SPECS, on_change=changes.append)
    bad = node.set_parameters([Parameter('rate_hz', value=math.nan)])[0]
    assert not bad.successful and 'rate_hz' in bad.reason and ps['rate_hz'] == 100.0
    bad = node.set_parameters([Parameter('kp', value=[1.0, -2.0, 3.0])])[0]
    assert not bad.successful and 'kept [5.0, 5.0, 20.0]' in bad.reason
    ok = node.set_parameters([Parameter('mode', value='pid')])[0]
    assert ok.successful and ps['mode'] == 'pid' and changes == [{'mode': 'pid'}]


def test_cross_parameter_rule(node):
    def validate(values):
        if values['rate_hz'] > 500 and values['mode'] == 'pd':
            raise ValueError('rate_hz above 500 needs mode pid')
    ps = ParameterSet(node, SPECS, validate=validate)
    res = node.set_parameters([Parameter('rate_hz', value=800.0)])[0]
    assert not res.successful and 'needs mode pid' in res.reason and ps['rate_hz'] == 100.0


def test_isolated_domain_gives_children_the_fast_announcing_discovery_profile(monkeypatch):
    for variable in ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE'):
        monkeypatch.delenv(variable, raising=False)

    ns = {'p': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
    announce = ET.parse(FASTDDS_PROFILE).find('.//p:discovery_config/p:leaseAnnouncement', ns)
    assert int(announce.find('p:sec', ns).text) + int(announce.find('p:nanosec', ns).text) * 1e-9 == 0.2
    writer = ET.parse(FASTDDS_PROFILE).find('.//p:data_writer[@is_default_profile="true"]', ns)
    heartbeat = writer.find('p:times/p:heartbeatPeriod', ns)   # a lost sample's recovery (default 3 s)
    assert int(heartbeat.find('p:sec', ns).text) + int(heartbeat.find('p:nanosec', ns).text) * 1e-9 == 0.05
    with isolated_domain() as (domain, env):
        assert env['ROS_DOMAIN_ID'] == str(domain) and env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
        assert env['FASTRTPS_DEFAULT_PROFILES_FILE'] == env['FASTDDS_DEFAULT_PROFILES_FILE'] == FASTDDS_PROFILE
        assert os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] == FASTDDS_PROFILE  # for this process's participants


def test_range_bounds_are_inclusive():
    """min and max are allowed values (a range check that refused them would refuse rate_hz = 1 and 1000)."""
    assert check_value(SPECS[1], 1.0) is None and check_value(SPECS[1], 1000.0) is None
    assert check_value(SPECS[0], [0.0, 0.0, 0.0]) is None
    assert 'must be >= 1.0' in check_value(SPECS[1], 0.999)
    assert 'must be <= 1000.0' in check_value(SPECS[1], 1000.001)


def test_a_value_of_the_wrong_type_is_refused_naming_the_parameter(node):
    """`ros2 param set /node rate_hz five`: the reason names rate_hz and the value (rclpy's own type check, before
    any callback, says only "Wrong parameter type"); an integer for a float is the float it means."""
    ps = ParameterSet(node, SPECS)
    bad = node.set_parameters([Parameter('rate_hz', value='five')])[0]
    assert not bad.successful and "rate_hz = 'five' refused: must be a number" in bad.reason
    assert ps['rate_hz'] == 100.0
    bad = node.set_parameters([Parameter('mode', value=3)])[0]
    assert not bad.successful and 'mode = 3 refused: must be text' in bad.reason
    assert node.set_parameters([Parameter('rate_hz', value=50)])[0].successful
    assert ps['rate_hz'] == 50.0 and isinstance(ps['rate_hz'], float)


def test_type_refusal_of_scalars_and_lists():
    assert check_value(SPECS[1], True) == 'rate_hz = True refused: must be a number'
    assert check_value(SPECS[0], [1.0, 'x', 2.0]) == "kp = [1.0, 'x', 2.0] refused: must be a list of numbers"
    assert check_value(SPECS[0], 'stiff') == "kp = 'stiff' refused: must be a list"
    assert check_value(Param('priority', 0, 'an int'), 2.5) == 'priority = 2.5 refused: must be an integer'
    assert check_value(SPECS[1], 7) is None


def test_a_namespaced_node_refuses_a_plain_section_only_when_it_sets_parameters(tmp_path):
    """rcl gives a file's plain `NAME:` section to /NAME only: a section setting gains would be lost without a word
    under /uav2 (refused); an empty one (config/control.yaml sets nothing) loses nothing (accepted)."""
    from types import SimpleNamespace

    from quad_common.ros.ros_params import check_sections_reach
    node = SimpleNamespace(get_namespace=lambda: '/uav2', get_name=lambda: 'position_controller')
    setting, empty = tmp_path / 'setting.yaml', tmp_path / 'empty.yaml'
    setting.write_text('position_controller:\n  ros__parameters:\n    kp_x: 3.0\n')
    empty.write_text('position_controller:\n  ros__parameters: {}\n')
    check_sections_reach(node, ['--ros-args', '--params-file', str(empty)])
    with pytest.raises(ValueError, match='section reaches /position_controller only, not /uav2/position_controller'):
        check_sections_reach(node, ['--ros-args', '--params-file', str(setting)])
