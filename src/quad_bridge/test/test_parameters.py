"""The configurations built from mavlink_bridge's parameter values (quad_bridge.parameters): every BridgeConfig
field and every external pose setting from the parameter of its name, none from a default behind its back."""

import dataclasses

from quad_bridge.backend import BridgeConfig
from quad_bridge.parameters import SPECS, bridge_config, external_pose_config


def values_unlike_the_defaults() -> dict:
    """Every parameter at a value no default has (numbers scaled, strings and choices as given)."""
    out = {}
    for p in SPECS:
        v = p.default
        if isinstance(v, bool):
            v = not v
        elif isinstance(v, (int, float)):
            v = v * 1.5 + 0.25 if isinstance(v, float) else v + 1
        out[p.name] = v
    out['ardupilot_thrust_mode'], out['external_pose_frame'] = 'climb_rate', 'y_up'
    return out


def test_bridge_config_takes_each_of_its_fields_from_the_parameter_of_that_name():
    values = values_unlike_the_defaults()
    config = bridge_config(values)
    held = [f.name for f in dataclasses.fields(BridgeConfig) if f.name in values]
    assert held and {n: getattr(config, n) for n in held} == {n: values[n] for n in held}
    assert config.angle_boost == BridgeConfig().angle_boost   # not a parameter: the vehicle's (adopted) value


def test_external_pose_config_takes_every_external_pose_parameter():
    values = values_unlike_the_defaults()
    c = external_pose_config(values)
    assert (c.frame, c.max_rate_hz, c.timeout_s, c.max_age_s, c.max_speed_m_s, c.jump_margin_m) == (
        'y_up', values['external_pose_rate_hz'], values['external_pose_timeout_s'],
        values['external_pose_max_age_s'], values['external_pose_max_speed_mps'],
        values['external_pose_jump_margin_m'])
