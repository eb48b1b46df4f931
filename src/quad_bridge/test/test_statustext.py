"""quad_bridge.statustext: the vehicle's texts joined from their chunks and read back after a command."""

from quad_bridge.statustext import PARTIAL_S, StatusTexts

MS = 1_000_000
DENIED = 'Arming denied: Resolve system health failures first'   # 51 bytes: two chunks (PX4 sends it so)


def test_a_text_of_one_message_is_complete_at_once():
    texts = StatusTexts()
    assert texts.add(10 * MS, 6, 'PreArm: Need Position Estimate') == 'PreArm: Need Position Estimate'
    assert texts.since(0, 20 * MS) == ['PreArm: Need Position Estimate']


def test_chunks_are_joined_in_order_and_the_text_is_given_once():
    texts = StatusTexts()
    assert texts.add(10 * MS, 3, DENIED[:50], text_id=7, chunk_seq=0) is None
    assert texts.since(0, 11 * MS) == []
    assert texts.add(11 * MS, 3, DENIED[50:], text_id=7, chunk_seq=1) == DENIED
    assert texts.since(0, 12 * MS) == [DENIED]


def test_since_gives_what_arrived_after_the_command_only():
    texts = StatusTexts()
    texts.add(5 * MS, 6, 'an old text')
    texts.add(15 * MS, 6, 'Preflight Fail: No valid local position estimate')
    assert texts.since(10 * MS, 20 * MS) == ['Preflight Fail: No valid local position estimate']


def test_a_chunked_text_without_its_end_is_given_as_far_as_it_got():
    texts = StatusTexts()
    texts.add(10 * MS, 3, DENIED[:50], text_id=9, chunk_seq=0)
    assert texts.since(0, 10 * MS + int(PARTIAL_S * 1e9) - MS) == []
    assert texts.since(0, 10 * MS + int(PARTIAL_S * 1e9) + MS) == [DENIED[:50]]


def test_old_texts_are_dropped():
    texts = StatusTexts(keep_s=1.0)
    texts.add(0, 6, 'old')
    texts.add(1500 * MS, 6, 'new')
    assert texts.since(0, 1600 * MS) == ['new']


def test_wait_since_returns_when_the_vehicle_has_spoken_and_after_its_timeout_when_not():
    import threading
    import time

    texts = StatusTexts()
    sent_ns = time.time_ns()
    assert texts.wait_since(sent_ns, timeout_s=0.05) == []    # nothing said: the timeout
    speaker = threading.Thread(target=lambda: texts.add(time.time_ns(), 3, 'PreArm: Need Position Estimate'))
    speaker.start()
    got = texts.wait_since(sent_ns, timeout_s=30.0)          # a hang guard: it returns when the text is there
    speaker.join()
    assert got == ['PreArm: Need Position Estimate']
