"""A node's process under real-time scheduling (`realtime_priority` of mavlink_bridge and position_controller,
docs/bridge.md "Real-time scheduling"): every thread of the process, Fast DDS's included, under SCHED_FIFO at one
priority, as PX4 and companion stacks run their flight paths. One thread alone would not do: the thread on the
flight path needs the interpreter lock, which another Python thread preempted by an ordinary process would hold,
and its wake-up comes from a Fast DDS thread.

Threads started later inherit the policy from the thread that starts them (pthread's default), so applying it
once, after the node built its threads, covers the process. No rclpy here."""

import errno
import gc
import os

REFUSED_HOW = ('grant it: run as root or give the interpreter CAP_SYS_NICE (setcap cap_sys_nice+ep), or raise '
               'the real-time limit (`ulimit -r 99` in the shell that starts it, or `@GROUP - rtprio 99` in '
               '/etc/security/limits.conf, systemd LimitRTPRIO=99); or set realtime_priority: 0')


def thread_ids(pid='self') -> list[int]:
    """The ids of the process's threads (Linux: /proc/PID/task)."""
    try:
        return sorted(int(t) for t in os.listdir(f'/proc/{pid}/task'))
    except FileNotFoundError:   # not Linux: the calling thread only
        return [0]


def apply_realtime_priority(priority: int, tids=thread_ids, setter=None) -> str:
    """Puts every thread of this process under SCHED_FIFO at `priority` (1..99); 0: nothing. Threads that appear
    while it runs are taken too. Returns what it did, for the log and the diagnostics; raises PermissionError
    with the parameter, the value and how to grant it when the system refuses (EPERM: no CAP_SYS_NICE, RLIMIT_RTPRIO
    below the priority)."""
    if not 1 <= priority <= 99:
        if priority == 0:
            return 'off (SCHED_OTHER)'
        raise ValueError(f'realtime_priority = {priority!r} refused: must be 0 (off) or 1..99')
    setter = setter or os.sched_setscheduler
    done = set()
    while True:
        todo = [t for t in tids() if t not in done]
        if not todo:
            break
        for tid in todo:
            try:
                setter(tid, os.SCHED_FIFO, os.sched_param(priority))
            except ProcessLookupError:   # the thread ended meanwhile
                pass
            except PermissionError as exc:
                raise PermissionError(errno.EPERM, f'realtime_priority = {priority}: SCHED_FIFO refused by the system '
                                      f'({exc.strerror or exc}); {REFUSED_HOW}') from exc
            done.add(tid)
    return f'SCHED_FIFO {priority} ({len(done)} threads)'


def apply_or_report(priority: int, log_error, tids=thread_ids, setter=None) -> tuple[str, bool]:
    """apply_realtime_priority for a node: (what it did, False), or, when the system refuses, the refusal as an
    error in the log and ('refused: ...', True) for the diagnostics: the node runs on under the ordinary scheduler
    (a refusal is said loudly, never silent, and never stops a node that may be flying)."""
    try:
        return apply_realtime_priority(priority, tids, setter), False
    except PermissionError as exc:
        log_error(exc.strerror)
        return f'refused: {exc.strerror}', True


def policy_of(tid) -> tuple[int, int]:
    """(policy, priority) of a thread of this process."""
    return os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority


def freeze_startup_heap() -> int:
    """Collects once, then moves every object alive (the imports, the node: 40-100 thousand objects) out of the
    collector's reach (gc.freeze): a later full collection, which holds the interpreter lock and so stops every
    thread of the process for as long as it scans, then covers only what was allocated since. Returns the number of
    objects frozen."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()
