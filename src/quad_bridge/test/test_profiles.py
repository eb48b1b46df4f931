"""The shipped real-vehicle profiles: every key is a bridge parameter, the geofence is on with a valid
box that holds every shipped mission with 1 m to spare, and only the position controller may command."""

import numpy as np
import pytest

from quad_bridge.parameters import SPECS, validate
from quad_common.paths import REPO_ROOT, resolve_config
from quad_common.yaml_io import load_yaml

PROFILES = ['config/bridge_px4.yaml', 'config/bridge_ardupilot.yaml']


@pytest.mark.parametrize('profile', PROFILES)
def test_profile_has_the_geofence_on_around_every_mission(profile):
    values = load_yaml(resolve_config(profile))['mavlink_bridge']['ros__parameters']
    defaults = {p.name: p.default for p in SPECS}
    assert not set(values) - set(defaults), f'not bridge parameters: {set(values) - set(defaults)}'
    validate({**defaults, **values})
    assert values['geofence_enabled'] is True
    assert {**defaults, **values}['setpoint_source'] == 'position_controller'
    # SCHED_FIFO above every ordinary process, below the kernel's threaded interrupts (50) that deliver our UDP
    assert 1 <= values['realtime_priority'] < 50
    lo, hi = np.array(values['geofence_min_m']), np.array(values['geofence_max_m'])
    for mission in sorted((REPO_ROOT / 'config' / 'missions').glob('*.yaml')):
        points = np.array(load_yaml(mission)['waypoints'], float)
        assert np.all(points - 1.0 >= lo) and np.all(points + 1.0 <= hi), f'{mission.name} leaves {profile}\'s box'
