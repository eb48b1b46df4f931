"""BagRecorder.flush: the chunk reaches the file at once, the fsync runs in a thread of its own (a disk that takes
its time does not stop the recorder's thread), and close waits for it."""

import threading

from quad_bringup.recording import recorder
from quad_bringup.recording.recorder import DEFAULT_TOPICS, BagRecorder, open_bag_reader

ODOM_CDR = bytes(4 + 8 + 4 + 8)   # a short payload: the bag stores bytes, it does not decode them


def test_flush_returns_while_the_disk_is_still_syncing_and_close_waits_for_it(tmp_path, monkeypatch):
    release, syncing, synced = threading.Event(), threading.Event(), []

    def slow_fsync(fd):
        syncing.set()
        assert release.wait(30.0), 'the test never released the fsync'
        synced.append(fd)

    monkeypatch.setattr(recorder.os, 'fsync', slow_fsync)
    bag = BagRecorder(tmp_path / 'bag')
    bag.add_topic('odom', DEFAULT_TOPICS['odom'])
    mcap = next((tmp_path / 'bag').glob('*.mcap'))
    before = mcap.stat().st_size
    bag.write('odom', 1, ODOM_CDR)
    bag.flush()                        # returns with the fsync still held
    assert syncing.wait(30.0) and not synced
    assert mcap.stat().st_size > before   # the chunk is in the file (a SIGKILL now loses nothing of it)
    bag.write('odom', 2, ODOM_CDR)
    bag.flush()                        # one fsync at a time: this one leaves it to the one in progress
    closing = threading.Thread(target=bag.close)
    closing.start()
    release.set()
    closing.join(30.0)
    assert not closing.is_alive() and len(synced) == 1
    reader, repair = open_bag_reader(tmp_path / 'bag')
    try:
        assert repair is None and reader.message_count == 2
    finally:
        reader.close()
