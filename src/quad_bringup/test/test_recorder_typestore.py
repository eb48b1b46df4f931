"""recorder.typestore: the contract's types from their cached Jazzy definitions, the same as rosbags' whole store."""

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from quad_bringup.recording import recorder


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    """A process's first typestore(): no store built yet, an empty cache folder."""
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path))
    monkeypatch.setattr(recorder, '_CONTRACT_STORE', None)
    monkeypatch.setattr(recorder, '_FULL_STORE', None)
    return tmp_path / 'quadflight'


def _cached(cache):
    return list(cache.glob('rosbags-jazzy-contract-*.pickle'))


def test_the_contract_store_has_jazzys_definitions_hashes_and_bytes(fresh):
    recorder.typestore()                      # the first: takes them from the whole store, caches them
    assert len(_cached(fresh)) == 1
    recorder._CONTRACT_STORE = recorder._FULL_STORE = None
    store = recorder.typestore()              # a later process: from the cache alone
    assert recorder._FULL_STORE is None and store is recorder._CONTRACT_STORE
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    assert set(recorder.CONTRACT_MSGTYPES) <= set(store.types)
    for msgtype in store.types:
        assert store.generate_msgdef(msgtype) == jazzy.generate_msgdef(msgtype), msgtype
        assert store.hash_rihs01(msgtype) == jazzy.hash_rihs01(msgtype), msgtype
    odometry = 'nav_msgs/msg/Odometry'
    raw = jazzy.serialize_cdr(jazzy.types[odometry](
        header=jazzy.types['std_msgs/msg/Header'](stamp=jazzy.types['builtin_interfaces/msg/Time'](sec=3, nanosec=4),
                                                  frame_id='map'),
        child_frame_id='base_link',
        pose=jazzy.types['geometry_msgs/msg/PoseWithCovariance'](
            pose=jazzy.types['geometry_msgs/msg/Pose'](
                position=jazzy.types['geometry_msgs/msg/Point'](x=1.0, y=2.0, z=3.0),
                orientation=jazzy.types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)),
            covariance=np.arange(36, dtype=np.float64)),
        twist=jazzy.types['geometry_msgs/msg/TwistWithCovariance'](
            twist=jazzy.types['geometry_msgs/msg/Twist'](
                linear=jazzy.types['geometry_msgs/msg/Vector3'](x=0.5, y=0.0, z=0.0),
                angular=jazzy.types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.1)),
            covariance=np.zeros(36))), odometry)
    decoded = store.deserialize_cdr(raw, odometry)
    assert decoded.pose.pose.position.z == 3.0 and decoded.child_frame_id == 'base_link'
    assert bytes(store.serialize_cdr(decoded, odometry)) == bytes(raw)


def test_a_type_outside_the_contract_gets_the_whole_store(fresh):
    recorder.typestore()   # the cache made
    recorder._CONTRACT_STORE = recorder._FULL_STORE = None
    assert 'std_msgs/msg/String' not in recorder.typestore().types
    store = recorder.typestore('std_msgs/msg/String')
    assert 'std_msgs/msg/String' in store.types and store is recorder._FULL_STORE
    assert recorder.typestore() is store   # a superset from then on


def test_a_damaged_cache_is_rebuilt(fresh):
    recorder.typestore()
    [path] = _cached(fresh)
    path.write_bytes(b'not a pickle')
    recorder._CONTRACT_STORE = recorder._FULL_STORE = None
    assert set(recorder.CONTRACT_MSGTYPES) <= set(recorder.typestore().types)
    assert recorder.contract_fielddefs() == recorder.type_closure(get_typestore(Stores.ROS2_JAZZY),
                                                                  recorder.CONTRACT_MSGTYPES)


def test_the_closure_holds_every_type_a_field_uses():
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    closure = recorder.type_closure(jazzy, ['nav_msgs/msg/Odometry'])
    assert set(closure) == {'nav_msgs/msg/Odometry', 'std_msgs/msg/Header', 'builtin_interfaces/msg/Time',
                            'geometry_msgs/msg/PoseWithCovariance', 'geometry_msgs/msg/Pose',
                            'geometry_msgs/msg/Point', 'geometry_msgs/msg/Quaternion',
                            'geometry_msgs/msg/TwistWithCovariance', 'geometry_msgs/msg/Twist',
                            'geometry_msgs/msg/Vector3'}
