import os

import pytest

from quad_common.vehicle import load_vehicle, vehicle_from_dict

CONFIG = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'config', 'vehicles')
BASE = dict(mass_kg=0.03, inertia_kgm2=[1.43e-5, 1.43e-5, 2.89e-5], arm_length_m=0.046, k_eta=2.3e-8,
            k_m=7.8e-10, rotor_speed_min_radps=0.0, rotor_speed_max_radps=2500.0)


def test_shipped_vehicles_load():
    cf = load_vehicle(os.path.join(CONFIG, 'crazyflie.yaml'))
    assert cf.mass_kg == 0.03 and cf.thrust_max_n == pytest.approx(4 * 2.3e-8 * 2500**2)
    assert load_vehicle(os.path.join(CONFIG, 'px4_quad.yaml')).thrust_to_weight > 2


@pytest.mark.parametrize('key,value,words', [
    ('mass_kg', 0.0, 'mass_kg = 0.0'), ('mass_kg', float('nan'), 'mass_kg = nan'),
    ('inertia_kgm2', [1e-5, -1e-5, 1e-5], 'inertia_kgm2'), ('layout', 'hex', "layout = 'hex'"),
    ('rotor_speed_max_radps', 100.0, 'cannot lift'),
])
def test_bad_fields_are_named(key, value, words):
    with pytest.raises(ValueError, match=words.replace('[', r'\[')):
        vehicle_from_dict(dict(BASE, **{key: value}))


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ValueError, match='file not found'):
        load_vehicle(tmp_path / 'nope.yaml')
    (tmp_path / 'bad.yaml').write_text('mass_kg: [1,\n')
    with pytest.raises(ValueError, match='not valid YAML'):
        load_vehicle(tmp_path / 'bad.yaml')
