"""A second vehicle on the link: two senders as one system id found from MAVLink's packet sequence
numbers; a lossy or reordering link with one sender is not; other vehicles' system ids reported."""

import random

from quad_bridge.peers import LinkPeers

RATE_HZ = 150.0   # packets per second of one vehicle's telemetry


def _feed(peers, seqs, system=1):
    for k, seq in enumerate(seqs):
        peers.seen(system, 1, seq % 256, k / RATE_HZ)
    return len(seqs) / RATE_HZ


def test_one_sender_through_a_lossy_reordering_link_is_one_vehicle():
    rng = random.Random(3)
    seqs = [s for s in range(600) if rng.random() > 0.2]   # 20 % lost, across three wrap-arounds
    for k in range(10, len(seqs) - 1, 97):                  # and a reordered pair now and then
        seqs[k], seqs[k + 1] = seqs[k + 1], seqs[k]
    peers = LinkPeers()
    now_s = _feed(peers, seqs)
    assert peers.duplicate(1, 1, now_s) == ''
    assert peers.refusal(1, 1, False, now_s) == ''


def test_two_senders_interleaving_in_bursts_are_two_vehicles():
    a, b, seqs = 40, 250, []
    for burst in range(60):   # each sends a tick's burst of 3-6 packets in turn
        n = 3 + burst % 4
        if burst % 2:
            seqs += range(a, a + n)
            a += n
        else:
            seqs += range(b, b + n)
            b += n
    peers = LinkPeers()
    now_s = _feed(peers, seqs)
    why = peers.duplicate(1, 1, now_s)
    assert 'two vehicles send as system 1 component 1' in why
    assert peers.refusal(1, 1, True, now_s) == why
    assert peers.duplicate(1, 1, now_s + 3.0) == ''   # gone once the window has passed


def test_other_vehicles_are_reported_and_refuse_only_a_first_heartbeat_target():
    peers = LinkPeers()
    peers.seen(1, 1, 0, 0.0, vehicle_heartbeat=True)
    peers.seen(2, 1, 0, 0.5, vehicle_heartbeat=True)
    peers.seen(255, 190, 0, 0.5)   # a ground station: not a vehicle heartbeat
    assert peers.other_vehicles(1, 1.0) == [2]
    assert 'set target_system' in peers.refusal(1, 1, False, 1.0)
    assert peers.refusal(1, 1, True, 1.0) == ''
    assert peers.other_vehicles(1, 5.0) == []


def test_signing_problems_name_signing():
    from quad_bridge.signing import signing_problem
    assert 'signing_key_file is empty' in signing_problem(False, 5, 0, 0)
    assert 'failed the MAVLink 2 signature check' in signing_problem(True, 5, 5, 0)
    assert 'the vehicle does not sign' in signing_problem(True, 0, 0, 7)
    assert signing_problem(True, 5, 0, 0) == '' and signing_problem(False, 0, 0, 0) == ''
