"""node_main.lean_log_caller: rclpy's logger finds a log call's caller from the frame's file, not through inspect's
source search, and its per-caller filters (once, skip_first) work as before."""

import inspect
import os

import pytest
import rclpy.logging
from rclpy.impl import rcutils_logger

from quad_common.ros.node_main import lean_log_caller


@pytest.fixture
def lean(monkeypatch):
    monkeypatch.setattr(rcutils_logger, 'inspect', rcutils_logger.inspect)   # put back after the test
    lean_log_caller()


def test_a_log_call_does_not_search_the_source(lean, monkeypatch, capfd):
    def no_source_search(*args, **kwargs):
        raise AssertionError('inspect.getframeinfo called')

    monkeypatch.setattr(inspect, 'getframeinfo', no_source_search)
    rclpy.logging.get_logger('lean_log_test').info('hello')
    assert 'hello' in capfd.readouterr().err


def test_the_caller_is_this_frames_function_file_and_line(lean):
    frame = inspect.currentframe()
    line = frame.f_lineno
    caller = rcutils_logger.CallerId(frame)
    assert caller.function_name == 'test_the_caller_is_this_frames_function_file_and_line'
    assert caller.file_path == os.path.abspath(__file__)
    assert caller.line_number == line + 1   # the line that made the CallerId


def test_once_and_skip_first_are_per_call_site(lean, capfd):
    logger = rclpy.logging.get_logger('lean_log_test')
    for _ in range(2):
        logger.info('first site once', once=True)
    logger.info('second site once', once=True)
    for _ in range(2):
        logger.info('skipped once', skip_first=True)
    err = capfd.readouterr().err
    assert err.count('first site once') == 1 and err.count('second site once') == 1
    assert err.count('skipped once') == 1
